"""Recordings: every run of the executive written to an MCAP file as it happens.

The executive's records (JSON messages, one JSON schema each): ``/scene`` (the world model as
scene-file data), ``/robot_state``, ``/command`` (setpoints and base twists sent), ``/plan``,
``/transitions`` (the state machine), ``/detections``, ``/events`` (monitor violations, results).
Beside them, what a viewer reads (:mod:`~rlgp_exec.executive.ros_record`): ROS 2 channels (``ros2msg``
schemas, CDR) - ``/robot_description``, ``/tf``, ``/tf_static``, ``/joint_states``, ``/odom`` - and
Foxglove scene entities (``/scene_entities``, ``/plan_path``), so Foxglove opens a recording as a robot
in its world. Each is written with the record it comes from, at its time. When the executive senses by
camera, :class:`~rlgp_exec.executive.camera_record.CameraTap` adds the head camera's frames through
``write_ros``: ``sensor_msgs/msg/CompressedImage`` (JPEG) and ``sensor_msgs/msg/CameraInfo`` on channels
named like the robot's topics.

Messages are written unchunked and reach the file at least every ``FLUSH_S`` and after every transition,
plan and event, so a killed process leaves a file that :func:`read_recording` reads up to the last
complete record. A write that fails (a full disk, an I/O error) stops the recording instead of raising:
the file keeps what reached it, and ``Recorder.error`` and the ``on_error`` callback say why.

:func:`read_recording` parses the MCAP records itself, bounded by each record's declared length, so that
every prefix of a recording reads (a truncated file yields its complete records and where it was cut) and
every malformed record is a :class:`RecordingError` naming the file, the record's offset and what is wrong.
"""

from __future__ import annotations

import contextlib
import errno
import json
import logging
import math
import os
import struct
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import IO, Any, Protocol

from mcap.writer import CompressionType, Writer

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive import ros_messages as rm
from rlgp_exec.executive.ros_record import ROS_CHANNELS, RosView

__all__ = [
    "CAMERA_TYPES", "CHANNELS", "MAX_RECORD", "SCHEMAS", "RecordSink", "Recorder", "Recording", "RecordingError",
    "read_recording",
]

COMPRESSED, INFO = "sensor_msgs/msg/CompressedImage", "sensor_msgs/msg/CameraInfo"
CAMERA_TYPES = (COMPRESSED, INFO)  # the message types recorded beside the executive's channels

log = logging.getLogger(__name__)

FLUSH_S = 0.05  # [s] at most this much data is lost when the process is killed
SPOOL_MAX = 1 << 16  # [bytes] held before a write reaches the file regardless of FLUSH_S
MAX_RECORD = 64 << 20  # [bytes] a record of a recording is at most this (a plan's message: ~100 kB)
CHANNELS = ("/scene", "/robot_state", "/command", "/plan", "/transitions", "/detections", "/events")
_URGENT = {"/scene", "/plan", "/transitions", "/events"}
STATE_VIEW_S = 0.02  # [s] robot states closer than this (stamps) to the last one derive no viewer messages

#: each record's JSON schema (what a JSON viewer shows as its fields)
SCHEMAS: dict[str, dict[str, Any]] = {
    "/scene": {"description": "the world model as scene-file data",
               "required": ["scene", "robot", "fixture", "object"]},
    "/robot_state": {"description": "measured joints [rad, m] and odometry (x, y [m], yaw [rad]) at stamp [s]",
                     "required": ["stamp", "names", "q", "dq", "base"]},
    "/command": {"description": "setpoints and base twist sent to the robot", "required": ["names", "q", "dq"]},
    "/plan": {"description": "the plan's summary and its phases' joint paths (n, nq)", "required": ["phases"]},
    "/transitions": {"description": "a state machine transition", "required": ["to"]},
    "/detections": {"description": "sensed poses (4x4, world frame) by object or frame", "required": ["poses"]},
    "/events": {"description": "monitor violations, plan failures and task results", "required": ["kind"]},
}
MAGIC = b"\x89MCAP0\r\n"

_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END = 0x01, 0x02, 0x03, 0x04, 0x05, 0x06, 0x0F
_OPCODES = {
    0x01: "Header", 0x02: "Footer", 0x03: "Schema", 0x04: "Channel", 0x05: "Message", 0x06: "Chunk",
    0x07: "MessageIndex", 0x08: "ChunkIndex", 0x09: "Attachment", 0x0A: "AttachmentIndex", 0x0B: "Statistics",
    0x0C: "Metadata", 0x0D: "MetadataIndex", 0x0E: "SummaryOffset", 0x0F: "DataEnd",
}


class RecordingError(RlgpError):
    """A recording cannot be written or read."""


def _json_default(o: Any) -> Any:
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "value"):  # enums
        return o.value
    raise TypeError(f"cannot record {type(o).__name__}")


class RecordSink(Protocol):
    """What the executive records into: a :class:`Recorder`, a live view, both (``foxglove_live.Tee``);
    ``write_ros`` takes the camera's messages (``camera_record``)."""

    on_error: Callable[[str], None] | None

    def write(self, topic: str, data: dict[str, Any], t_wall: float | None = None) -> None: ...

    def write_ros(self, topic: str, typename: str, payload: bytes, t_wall: float) -> None: ...


class _Spool:
    """The MCAP writer's output stream: bytes held in memory until the recorder writes them out, so a
    failed write leaves no half-flushed buffer behind (the file is always a prefix of the stream)."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.offset = 0  # bytes the writer has produced

    def write(self, data: bytes) -> int:
        self.buf += data
        self.offset += len(data)
        return len(data)

    def tell(self) -> int:  # the writer's footer points at file offsets
        return self.offset


class Recorder:
    """Writes one MCAP file; thread-safe; ``close()`` finishes it (summary and footer).

    Writing never raises an I/O error: the first ``OSError`` (disk full, EIO, a closed descriptor) ends
    the recording. The file keeps every byte written before it (it reads as a truncated recording),
    ``error`` holds the reason, it is logged once, ``on_error(reason)`` is called once (outside the
    recorder's lock: it may write), and later writes and ``close()`` do nothing. ``write`` raises only
    when called wrongly: an unknown channel, data that is not JSON, a time that is not a finite >= 0.
    """

    def __init__(
        self,
        path: str | Path,
        profile: str = "rlgp-exec",
        on_error: Callable[[str], None] | None = None,
        viewer: bool = True,
    ) -> None:
        """``viewer``: also write the ROS 2 and scene-entity channels (module docstring)."""
        self.path = Path(path)
        self.on_error = on_error
        self.error: str | None = None  # why the recording stopped early (None: it did not)
        self.n_messages = 0
        self.n_bytes = 0  # bytes that reached the file
        self._failure = ""  # the OSError that stopped it, in words
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fd: int | None = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC | os.O_CLOEXEC, 0o644)
        except OSError as e:
            raise RecordingError(f"cannot write recording {self.path}: {e.strerror or e}") from e
        self._lock = threading.Lock()
        self._spool = _Spool()
        self._w = Writer(self._spool, use_chunking=False, compression=CompressionType.NONE)  # type: ignore[arg-type]
        self._w.start(profile=profile, library="rlgp-exec")
        self._channels: dict[str, int] = {}
        for topic in CHANNELS:
            sid = self._w.register_schema(
                name=f"rlgp_exec{topic.replace('/', '.')}",
                encoding="jsonschema",
                data=json.dumps({"type": "object", "title": topic, **SCHEMAS[topic]}).encode(),
            )
            self._channels[topic] = self._w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self._view = RosView() if viewer else None
        self._view_lock = threading.Lock()
        self._view_failed: set[str] = set()  # topics whose records could not be derived (logged once)
        self._last_state_view = -math.inf  # [s] wall time of the last robot state derived
        self._schema_ids: dict[bytes, int] = {}
        self._ros_types: dict[str, str] = {}  # channels added by write_ros: topic -> message type
        if viewer:
            for ch in ROS_CHANNELS.values():
                self._channels[ch.topic] = self._w.register_channel(
                    topic=ch.topic, message_encoding=ch.message_encoding,
                    schema_id=self._schema_id(ch.schema_name, ch.schema_encoding, ch.schema_data))
        self._last_flush = time.monotonic()
        with self._lock:
            if self._flush() is not None:  # the file cannot take its first bytes: nothing to record into
                raise RecordingError(f"cannot write recording {self.path}: {self._failure}")

    @property
    def closed(self) -> bool:
        """Closed, or stopped by a write error (``error``)."""
        return self._fd is None

    def write(self, topic: str, data: dict[str, Any], t_wall: float | None = None) -> None:
        """Record ``data`` on ``topic`` (one of CHANNELS) at wall time ``t_wall`` [s] (now by default)."""
        if topic not in CHANNELS:
            raise RecordingError(f"unknown recording channel {topic!r}; valid: {list(CHANNELS)}")
        t = time.time() if t_wall is None else t_wall
        if not (math.isfinite(t) and 0.0 <= t < 1.8e10):
            raise RecordingError(f"recording {topic}: t_wall must be a wall time [s] >= 0, got {t!r}")
        t_ns = int(t * 1e9)
        payload = json.dumps(data, default=_json_default, allow_nan=True).encode()
        with self._view_lock:  # not under the writer's lock: a plan's FK must not hold up the control loop's writes
            viewer = self._derive(topic, data, t) if self._fd is not None else []
        reason = None
        with self._lock:
            if self._fd is None:
                return  # closed or stopped: late messages from a stopping thread are dropped, never raised
            self._w.add_message(self._channels[topic], log_time=t_ns, data=payload, publish_time=t_ns)
            self.n_messages += 1
            for channel, derived in viewer:
                self._w.add_message(self._channels[channel], log_time=t_ns, data=derived, publish_time=t_ns)
            now = time.monotonic()
            if topic in _URGENT or now - self._last_flush >= FLUSH_S or len(self._spool.buf) >= SPOOL_MAX:
                self._last_flush = now
                reason = self._flush()
        if reason is not None:
            self._report(reason)

    def _schema_id(self, name: str, encoding: str, data: bytes) -> int:
        if data not in self._schema_ids:
            self._schema_ids[data] = self._w.register_schema(name=name, encoding=encoding, data=data)
        return self._schema_ids[data]

    def write_ros(self, topic: str, typename: str, payload: bytes, t_wall: float) -> None:
        """Record the CDR ``payload`` of ``typename`` (one of ``CAMERA_TYPES``) on the channel ``topic``, its
        first message registering it; raises only when called wrongly, like ``write``."""
        if typename not in CAMERA_TYPES:
            raise RecordingError(
                f"recording {topic}: message type {typename!r} not recorded; valid: {list(CAMERA_TYPES)}")
        if not topic.startswith("/") or topic in CHANNELS or topic in ROS_CHANNELS:
            raise RecordingError(f"recording: {topic!r} is not a free channel name (it starts with '/', it is not "
                                 f"one of the executive's or the viewer's)")
        if not (math.isfinite(t_wall) and 0.0 <= t_wall < 1.8e10):
            raise RecordingError(f"recording {topic}: t_wall must be a wall time [s] >= 0, got {t_wall!r}")
        if self._ros_types.setdefault(topic, typename) != typename:
            raise RecordingError(f"recording {topic}: a {typename} on a channel of {self._ros_types[topic]}")
        t_ns = int(t_wall * 1e9)
        reason = None
        with self._lock:
            if self._fd is None:
                return
            if topic not in self._channels:
                s = rm.ros_schema(typename)
                self._channels[topic] = self._w.register_channel(
                    topic=topic, message_encoding=s.message_encoding,
                    schema_id=self._schema_id(s.name, s.encoding, s.text.encode()))
            self._w.add_message(self._channels[topic], log_time=t_ns, data=payload, publish_time=t_ns)
            now = time.monotonic()
            if now - self._last_flush >= FLUSH_S or len(self._spool.buf) >= SPOOL_MAX:
                self._last_flush = now
                reason = self._flush()
        if reason is not None:
            self._report(reason)

    def _derive(self, topic: str, data: dict[str, Any], t: float) -> list[tuple[str, bytes]]:
        """The viewer's messages of a record (under ``_view_lock``); a record they cannot be made of is logged
        once per topic and the record itself kept (the executive's record is what a replay reads)."""
        if self._view is None:
            return []
        if topic == "/robot_state":  # thinned on the robot's clock: a lock-step simulation runs faster than the wall's
            stamp = data.get("stamp")
            ts = float(stamp) if isinstance(stamp, int | float) else t
            if abs(ts - self._last_state_view) < STATE_VIEW_S:
                return []
            self._last_state_view = ts
        try:
            return self._view.derive(topic, data, t)
        except Exception as e:  # a record the viewer cannot draw must not stop the recording, nor the task
            if topic not in self._view_failed:
                self._view_failed.add(topic)
                log.warning("recording %s: no viewer messages for a %s record: %s: %s",
                            self.path, topic, type(e).__name__, e)
            return []

    def _flush(self) -> str | None:
        """Write the spool to the file (under the lock); on an OSError stop and return the reason."""
        assert self._fd is not None
        buf = memoryview(self._spool.buf)
        done = 0
        try:
            while done < len(buf):  # os.write may take part of it (a nearly full disk)
                done += os.write(self._fd, buf[done:])
        except OSError as e:
            self.n_bytes += done
            buf.release()
            self._failure = f"{e.strerror or e} (errno {e.errno})"
            return self._stop(self._failure, owned=e.errno != errno.EBADF)
        self.n_bytes += done
        buf.release()
        del self._spool.buf[:]
        return None

    def _stop(self, why: str, owned: bool = True) -> str:
        assert self._fd is not None
        if owned:  # (not owned: closed under the recorder; its number may be another file's by now)
            with contextlib.suppress(OSError):
                os.close(self._fd)
        self._fd = None
        self._spool.buf.clear()
        self.error = (
            f"recording {self.path} stopped at message {self.n_messages}: {why}; the file keeps the "
            f"{self.n_bytes} bytes written before it (a truncated recording)"
        )
        return self.error

    def _report(self, reason: str) -> None:
        log.error("%s", reason)
        if self.on_error is not None:
            try:
                self.on_error(reason)
            except Exception:  # the callback's failure must not reach the control loop either
                log.exception("recording %s: on_error callback failed", self.path)

    def close(self) -> None:
        """Finish the file (summary, footer); never raises an I/O error (see the class)."""
        reason = None
        with self._lock:
            if self._fd is None:
                return
            self._w.finish()
            reason = self._flush()
            if reason is None:
                fd, self._fd = self._fd, None
                try:
                    os.close(fd)
                except OSError as e:  # e.g. EIO reported at close by a network file system
                    self.error = reason = f"recording {self.path}: closing it failed: {e.strerror or e}"
        if reason is not None:
            self._report(reason)
            return
        log.info("recording %s: %d messages", self.path, self.n_messages)

    def __del__(self) -> None:  # never closed: release the descriptor (the file reads as unfinished)
        fd = getattr(self, "_fd", None)
        if fd is not None:
            with contextlib.suppress(OSError):
                os.close(fd)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# ---------------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Recording:
    path: Path
    messages: tuple[tuple[str, float, dict[str, Any]], ...]  # (topic, t_wall [s], data)
    complete: bool  # the writer finished the file (footer and closing magic read)
    truncated_at: int | None = None  # unfinished: the offset [bytes] where reading stopped
    size: int = 0  # [bytes]
    offsets: tuple[int, ...] = ()  # each message's record offset [bytes], to name it in errors
    #: messages on each viewer channel (ROS 2, scene entities, camera): written for viewers, not replayed
    derived: Mapping[str, int] = field(default_factory=lambda: MappingProxyType({}))

    def topic(self, name: str) -> list[tuple[float, dict[str, Any]]]:
        return [(t, d) for tp, t, d in self.messages if tp == name]

    def where(self, i: int) -> str:
        """Message ``i`` as an error names it."""
        return f"{self.path}: {self.messages[i][0]} message at byte {self.offsets[i]}"

    @property
    def ending(self) -> str:
        """How the file ends, in words."""
        if self.complete:
            return "complete"
        if self.truncated_at is None or self.truncated_at >= self.size:
            return f"unfinished: it ends at byte {self.size} after a complete record, without the footer"
        cut = self.truncated_at
        return f"truncated at byte {cut}: the record there is cut off after {self.size - cut} bytes"


class _MalformedError(Exception):
    """A record's fields do not fit its body (turned into a RecordingError naming the record)."""


class _Fields:
    """One record's body, read field by field, never past its end."""

    def __init__(self, body: bytes) -> None:
        self.body, self.pos = body, 0

    def take(self, n: int, what: str) -> bytes:
        if n > len(self.body) - self.pos:
            raise _MalformedError(f"{what} needs {n} bytes, the record has {len(self.body) - self.pos} left")
        self.pos += n
        return self.body[self.pos - n : self.pos]

    def uint(self, n: int, what: str) -> int:
        return int.from_bytes(self.take(n, what), "little")

    def text(self, what: str) -> str:
        raw = self.take(self.uint(4, f"{what}'s length"), what)
        try:
            return raw.decode()
        except UnicodeDecodeError as e:
            raise _MalformedError(f"{what} is not UTF-8 ({e.reason} at {e.start})") from e

    def blob(self, what: str) -> bytes:
        return self.take(self.uint(4, f"{what}'s length"), what)

    def rest(self) -> bytes:
        self.pos, out = len(self.body), self.body[self.pos :]
        return out


def read_recording(path: str | Path) -> Recording:
    """Read every complete message of an MCAP recording (also one whose writer was killed or cut off).

    Raises :class:`RecordingError` when the file cannot be read, is not an MCAP recording, or holds a
    malformed record (the message names the record's offset and what was expected)."""
    p = Path(path)
    try:
        with open(p, "rb") as f:
            return _Reader(p, f, os.fstat(f.fileno()).st_size).read()
    except OSError as e:
        raise RecordingError(f"cannot read recording {p}: {e.strerror or e}") from e


class _Reader:
    def __init__(self, path: Path, f: IO[bytes], size: int) -> None:
        self.path, self.f, self.size = path, f, size
        self.schemas: dict[int, tuple[str, str, bytes]] = {}
        self.channels: dict[int, tuple[str, str, int]] = {}  # id: (topic, message encoding, schema id)
        self.messages: list[tuple[str, float, dict[str, Any]]] = []
        self.offsets: list[int] = []
        self.derived: dict[str, int] = {}
        self.camera: set[str] = set()  # the channels of camera messages (topics the robot names)
        self.data_end = False

    def _error(self, off: int, op: int, msg: str) -> RecordingError:
        kind = _OPCODES.get(op, f"opcode 0x{op:02x}")
        return RecordingError(f"{self.path}: {kind} record at byte {off}: {msg}")

    def _done(self, complete: bool, truncated_at: int | None) -> Recording:
        rec = Recording(
            self.path, tuple(self.messages), complete, truncated_at, self.size, tuple(self.offsets),
            MappingProxyType(dict(sorted(self.derived.items()))),
        )
        if not complete:
            log.warning("recording %s is %s: read %d messages", self.path, rec.ending, len(self.messages))
        return rec

    def read(self) -> Recording:
        not_mcap = f"{self.path} is not a readable MCAP recording"
        magic = self.f.read(len(MAGIC))
        if magic != MAGIC:
            if len(magic) < len(MAGIC) and MAGIC.startswith(magic):
                raise RecordingError(f"{not_mcap}: it ends at byte {len(magic)}, inside the MCAP magic")
            raise RecordingError(f"{not_mcap}: it does not start with the MCAP magic (got {magic[:8]!r})")
        off = len(MAGIC)
        first = True
        while True:
            head = self.f.read(9)
            op, length = (head[0], struct.unpack_from("<Q", head, 1)[0]) if len(head) == 9 else (-1, 0)
            if first and op not in (-1, _HEADER):
                raise RecordingError(f"{not_mcap}: its first record (byte {off}) is opcode 0x{op:02x}, not a Header")
            if length > MAX_RECORD:  # never a cut-off record: the writer writes none this large
                raise self._error(off, op, f"declares {length} bytes, more than the {MAX_RECORD} a record may have")
            body = self.f.read(length) if op != -1 else b""
            if op == -1 or len(body) < length:  # cut off (or the file shrank while being read)
                if first:
                    raise RecordingError(f"{not_mcap}: it ends at byte {self.size}, inside its Header record")
                return self._done(False, off)
            try:
                self._record(off, op, _Fields(body), first)
            except _MalformedError as e:
                raise self._error(off, op, str(e)) from None
            first = False
            off += 9 + length
            if op == _FOOTER:
                tail = self.f.read(len(MAGIC) + 1)
                if tail[: len(MAGIC)] != MAGIC:
                    if len(tail) < len(MAGIC) and MAGIC.startswith(tail):
                        return self._done(False, off)  # cut inside the closing magic
                    raise self._error(off - 9 - length, op, "is not followed by the closing MCAP magic")
                if len(tail) > len(MAGIC):
                    raise RecordingError(f"{self.path}: {self.size - off - len(MAGIC)} bytes after the closing magic")
                return self._done(True, None)

    def _record(self, off: int, op: int, r: _Fields, first: bool) -> None:
        if op == _HEADER:
            if not first:
                raise _MalformedError("a second Header (the file's first record is its only Header)")
            r.text("profile")
            r.text("library")
        elif op == _SCHEMA:
            sid = r.uint(2, "schema id")
            schema = (r.text("schema name"), r.text("schema encoding"), r.blob("schema data"))
            if sid == 0:
                raise _MalformedError("schema id 0 is reserved (it means no schema)")
            if self.schemas.setdefault(sid, schema) != schema:
                raise _MalformedError(f"schema {sid} declared again with other contents")
        elif op == _CHANNEL:
            self._channel(r)
        elif op == _MESSAGE:
            self._message(off, r)
        elif op == _DATA_END:
            r.uint(4, "data section crc")
            self.data_end = True
        elif op == _FOOTER:
            r.take(20, "summary offsets and crc")
        elif op == _CHUNK:
            raise _MalformedError("chunked: rlgp-exec reads the unchunked recordings it writes")
        # other records (indexes, statistics, attachments, metadata, future opcodes) carry nothing replayed

    def _channel(self, r: _Fields) -> None:
        cid = r.uint(2, "channel id")
        schema_id = r.uint(2, "schema id")
        topic = r.text("topic")
        encoding = r.text("message encoding")
        meta = _Fields(r.blob("metadata"))
        while meta.pos < len(meta.body):
            meta.text("metadata key")
            meta.text("metadata value")
        if schema_id != 0 and schema_id not in self.schemas:
            raise _MalformedError(
                f"channel {cid} ({topic}) refers to schema {schema_id}, which no Schema record before it declares"
            )
        schema = self.schemas.get(schema_id, ("", "", b""))
        camera = (topic not in CHANNELS and topic not in ROS_CHANNELS
                  and schema[:2] in {(t, "ros2msg") for t in CAMERA_TYPES})
        if topic not in CHANNELS and topic not in ROS_CHANNELS and not camera:
            raise _MalformedError(
                f"channel {cid}: topic {topic!r} is not a recording channel {[*CHANNELS, *ROS_CHANNELS]}, "
                f"nor a camera channel (schema {schema[0] or 'none'!r}; camera channels: ros2msg {list(CAMERA_TYPES)})"
            )
        expected = "json" if topic in CHANNELS else "cdr" if camera else ROS_CHANNELS[topic].message_encoding
        if encoding != expected:
            raise _MalformedError(f"channel {cid} ({topic}): message encoding {encoding!r}, expected {expected!r}")
        if self.channels.setdefault(cid, (topic, encoding, schema_id)) != (topic, encoding, schema_id):
            raise _MalformedError(f"channel {cid} declared again as {topic!r}, first as {self.channels[cid][0]!r}")
        if camera:
            self.camera.add(topic)

    def _message(self, off: int, r: _Fields) -> None:
        cid, _, log_time, _ = struct.unpack("<HIQQ", r.take(22, "channel id, sequence and times"))
        data = r.rest()
        if cid not in self.channels:
            raise _MalformedError(f"channel {cid}, which no Channel record before it declares")
        topic = self.channels[cid][0]
        if self.data_end:
            raise _MalformedError(f"({topic}) after the DataEnd record: messages belong in the data section")
        if topic in ROS_CHANNELS or topic in self.camera:  # a viewer's message: counted, not replayed
            self.derived[topic] = self.derived.get(topic, 0) + 1
            return
        try:
            msg = json.loads(data)
        except (ValueError, RecursionError) as e:  # RecursionError: nested deeper than the parser goes
            raise _MalformedError(f"({topic}) payload is not JSON: {type(e).__name__}: {e}") from None
        if not isinstance(msg, dict):
            raise _MalformedError(f"({topic}) payload is a JSON {type(msg).__name__}, expected an object")
        self.messages.append((topic, log_time / 1e9, msg))
        self.offsets.append(off)
