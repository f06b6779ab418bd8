"""Recordings: every run of the executive written to an MCAP file as it happens.

Channels (JSON messages with JSON-schema schemas, so Foxglove and the ``mcap`` CLI read them):
``/scene`` (the world model as scene-file data), ``/robot_state``, ``/command`` (setpoints and base
twists sent), ``/plan``, ``/transitions`` (the state machine), ``/detections``, ``/events`` (monitor
violations, results).

Messages are written unchunked and the file is flushed at least every ``FLUSH_S`` and after every
transition, plan and event, so a killed process leaves a file that :func:`read_recording` reads up to
the last complete record (``complete`` says whether the writer finished it).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

from mcap.exceptions import McapError
from mcap.records import Channel, Footer, Message, Schema
from mcap.stream_reader import StreamReader
from mcap.writer import CompressionType, Writer

from rlgp_exec.errors import RlgpError

__all__ = ["CHANNELS", "Recorder", "Recording", "RecordingError", "read_recording"]

log = logging.getLogger(__name__)

FLUSH_S = 0.05  # [s] at most this much data is lost when the process is killed
CHANNELS = ("/scene", "/robot_state", "/command", "/plan", "/transitions", "/detections", "/events")
_URGENT = {"/scene", "/plan", "/transitions", "/events"}


class RecordingError(RlgpError):
    """A recording cannot be written or read."""


def _json_default(o: Any) -> Any:
    if hasattr(o, "tolist"):
        return o.tolist()
    if hasattr(o, "value"):  # enums
        return o.value
    raise TypeError(f"cannot record {type(o).__name__}")


class Recorder:
    """Writes one MCAP file; thread-safe; ``close()`` finishes it (summary and footer)."""

    def __init__(self, path: str | Path, profile: str = "rlgp-exec") -> None:
        self.path = Path(path)
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f: IO[bytes] | None = open(self.path, "wb")  # noqa: SIM115 - closed in close()
        except OSError as e:
            raise RecordingError(f"cannot write recording {self.path}: {e.strerror or e}") from e
        self._w = Writer(self._f, use_chunking=False, compression=CompressionType.NONE)
        self._w.start(profile=profile, library="rlgp-exec")
        self._lock = threading.Lock()
        self._channels: dict[str, int] = {}
        for topic in CHANNELS:
            sid = self._w.register_schema(
                name=f"rlgp_exec{topic.replace('/', '.')}",
                encoding="jsonschema",
                data=json.dumps({"type": "object", "title": topic}).encode(),
            )
            self._channels[topic] = self._w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        self._last_flush = time.monotonic()
        self.n_messages = 0
        self._f.flush()

    @property
    def closed(self) -> bool:
        return self._f is None

    def write(self, topic: str, data: dict[str, Any], t_wall: float | None = None) -> None:
        """Record ``data`` on ``topic`` (one of CHANNELS) at wall time ``t_wall`` [s] (now by default)."""
        if topic not in self._channels:
            raise RecordingError(f"unknown recording channel {topic!r}; valid: {list(CHANNELS)}")
        t_ns = int((time.time() if t_wall is None else t_wall) * 1e9)
        payload = json.dumps(data, default=_json_default, allow_nan=True).encode()
        with self._lock:
            if self._f is None:
                return  # closed: late messages from a stopping thread are dropped, never raised
            self._w.add_message(self._channels[topic], log_time=t_ns, data=payload, publish_time=t_ns)
            self.n_messages += 1
            now = time.monotonic()
            if topic in _URGENT or now - self._last_flush >= FLUSH_S:
                self._f.flush()
                self._last_flush = now

    def close(self) -> None:
        with self._lock:
            if self._f is None:
                return
            try:
                self._w.finish()
            finally:
                self._f.close()
                self._f = None
        log.info("recording %s: %d messages", self.path, self.n_messages)

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


@dataclass(frozen=True)
class Recording:
    path: Path
    messages: tuple[tuple[str, float, dict[str, Any]], ...]  # (topic, t_wall [s], data)
    complete: bool  # the writer finished the file (False: the process died; read up to the last record)

    def topic(self, name: str) -> list[tuple[float, dict[str, Any]]]:
        return [(t, d) for tp, t, d in self.messages if tp == name]


def _records(f: IO[bytes]) -> Iterator[Any]:
    yield from StreamReader(f, skip_magic=False).records


def read_recording(path: str | Path) -> Recording:
    """Read every complete message of an MCAP recording (also one whose writer was killed)."""
    p = Path(path)
    try:
        f = open(p, "rb")  # noqa: SIM115
    except OSError as e:
        raise RecordingError(f"cannot read recording {p}: {e.strerror or e}") from e
    channels: dict[int, str] = {}
    out: list[tuple[str, float, dict[str, Any]]] = []
    complete = False
    n_bad = 0
    with f:
        try:
            for rec in _records(f):
                if isinstance(rec, Schema):
                    continue
                if isinstance(rec, Channel):
                    channels[rec.id] = rec.topic
                elif isinstance(rec, Message):
                    try:
                        data = json.loads(rec.data)
                    except ValueError:
                        n_bad += 1
                        continue
                    out.append((channels.get(rec.channel_id, "?"), rec.log_time / 1e9, data))
                elif isinstance(rec, Footer):
                    complete = True
        except (McapError, EOFError, ValueError, IndexError) as e:  # truncated by a kill, or not MCAP
            if not out and not channels:
                raise RecordingError(f"{p} is not a readable MCAP recording: {type(e).__name__}: {e}") from e
            log.warning("recording %s ends in a partial record (%s): read %d messages", p, e, len(out))
    if n_bad:
        log.warning("recording %s: %d messages were not JSON", p, n_bad)
    return Recording(p, tuple(out), complete)
