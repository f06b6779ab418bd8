"""Images when the camera is in the loop: the head camera's frames in recordings and in the live view.

:class:`CameraTap` feeds the executive's record sink (a :class:`~rlgp_exec.executive.recorder.Recorder`,
the live view, both through ``Tee``). It subscribes, through the HAL's Zenoh session, to the camera's
``sensor_msgs/Image`` and ``CameraInfo`` (keys ``camera_image`` and ``camera_info`` of the robot's key
map) and hands the sink, through its ``write_ros``, a ``sensor_msgs/msg/CompressedImage`` (JPEG) and the
``CameraInfo`` of the same frame, on channels named like the robot's own topics
(``/hsrb/head_rgbd_sensor/rgb/image_rect_color/compressed``, ``/hsrb/head_rgbd_sensor/rgb/camera_info``),
thinned to ``rate_hz`` on the robot's clock. A robot that publishes only compressed images
(``camera_compressed``: ``.../image_rect_color/compressed``, JPEG or PNG) has them recorded as they are:
the image bytes and format untouched, only the header's stamp moved onto the recording's clock. The first
kind of frame the tap receives (raw or compressed) is the one it records; frames of the other kind are
counted (``other_kind``) and left, so a robot publishing both is recorded once.

Neither the control loop nor the camera waits on it: Zenoh's callback reads only the image's stamp and
leaves the payload in a one-slot queue (the newest wins; one it replaces is counted as dropped); a worker
thread parses it (ros_image's parsers: a bad payload is counted under its reason, never raised),
JPEG-encodes it (cv2, which releases the GIL) and writes; a compressed frame is decoded only to check it
against the CameraInfo.

Clock: a frame's header keeps its own stamp (when it was taken, not when it arrived), moved onto the
recording's clock - the wall time the viewer channels' TF is stamped with, the time a robot state
arrives - by the robot's joint states (their stamps peeked, nothing decoded): the offset
``t_arrival - stamp``, its least over the last ``OFFSET_WINDOW_S`` (the least-delayed state), so a viewer
draws each frame over the TF of the instant it shows.

:class:`LocalFrameTap` records a local camera's frames (``run --camera VIDEO --calibration FILE``, which
bypasses the robot's camera topics) on the same channels: the undistorted frame as JPEG and the
calibration's pinhole model (the undistorted image's) as CameraInfo, in the head camera's optical frame,
stamped with the wall time the frame was read (the recording's clock).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import struct
import threading
import time
from collections import deque
from typing import Any

import cv2

from rlgp_exec.executive.recorder import CAMERA_TYPES, COMPRESSED, INFO, RecordSink
from rlgp_exec.hal import ros_image as ri
from rlgp_exec.hal.ros_codec import Rejected, _header, _ser, decode
from rlgp_exec.hal.validate import RejectCounter, guarded
from rlgp_exec.hal.zenoh_keys import KeyMap

__all__ = ["CAMERA_TYPES", "COMPRESSED", "DEFAULT_RATE_HZ", "INFO", "CameraTap", "LocalFrameTap", "camera_topics"]

log = logging.getLogger(__name__)

DEFAULT_RATE_HZ = 2.0  # [Hz] frames recorded per second of the robot's clock
JPEG_QUALITY = 80
OFFSET_WINDOW_S = 1.0  # [s] robot states this recent estimate the robot clock's offset
RESET_S = 1.0  # [s] a stamp this far behind the last recorded one is a restarted robot clock
_CDR_LE = b"\x00\x01\x00\x00"


def camera_topics(keys: KeyMap) -> tuple[str, str]:
    """The channels of the compressed images and of their CameraInfo: the robot's topics (namespace included)."""
    return "/" + keys["camera_compressed"].key, "/" + keys["camera_info"].key


def _peek_stamp(payload: bytes) -> float | None:
    """A little-endian CDR message's header stamp [s] (its first fields), None when it has none."""
    if len(payload) < 12 or payload[:4] != _CDR_LE:
        return None
    sec, ns = struct.unpack_from("<iI", payload, 4)
    return sec + ns * 1e-9


class CameraTap:
    """The camera's frames into ``sink`` (module docstring); ``close()`` it before the sink."""

    def __init__(self, sink: RecordSink, session: Any, keys: KeyMap, rate_hz: float = DEFAULT_RATE_HZ,
                 quality: int = JPEG_QUALITY) -> None:
        if not (math.isfinite(rate_hz) and 0 < rate_hz <= 30):
            raise ValueError(f"camera recording rate must be in (0, 30] Hz, got {rate_hz!r}")
        self.sink, self.period, self.quality = sink, 1.0 / rate_hz, int(quality)
        self.image_topic, self.info_topic = camera_topics(keys)
        self.rejects = RejectCounter("camera recording")
        self.received = self.thinned = self.dropped = self.written = self.other_kind = 0
        self._cond = threading.Condition()
        self._kind: str | None = None  # "raw" or "compressed": the first frame's kind, the one recorded
        self._slot: tuple[float | None, str, bytes] | None = None
        self._closed = False
        self._last_kept = -math.inf  # [s] robot clock: the last frame recorded
        self._info: Any = None  # the latest valid CameraInfo message
        self._offsets: deque[tuple[float, float]] = deque()  # (t_arrival [s], t_arrival - stamp [s]) of states
        self._offset_lock = threading.Lock()
        self._worker = threading.Thread(target=self._run, name="camera-record", daemon=True)
        self._worker.start()
        self._subs: list[Any] = []
        try:
            for name, fn in (("joint_states", self._on_state), ("camera_info", self._on_info),
                             ("camera_image", self._on_image), ("camera_compressed", self._on_compressed)):
                key = keys[name].key
                self._subs.append(session.declare_subscriber(key, guarded(self.rejects, name, fn, key)))
        except BaseException:  # a session that refuses one: nothing left running
            self.close()
            raise
        log.info("camera recording: %s at %.3g Hz as %s", keys["camera_image"].key, rate_hz, self.image_topic)

    # ------------------------------------------------------------------ Zenoh's side (its threads)
    def _on_state(self, payload: bytes) -> None:
        t = time.time()
        stamp = _peek_stamp(payload)
        if stamp is None:
            return  # (the HAL counts its bad joint states)
        with self._offset_lock:
            self._offsets.append((t, t - stamp))
            while self._offsets[0][0] < t - OFFSET_WINDOW_S:
                self._offsets.popleft()

    def _offset(self) -> float | None:
        with self._offset_lock:
            return min(o for _, o in self._offsets) if self._offsets else None

    def _on_info(self, payload: bytes) -> None:
        m = ri.parse_camera_info(payload)
        if isinstance(m, Rejected):
            self.rejects.reject(m.key, m.reason)
            return
        msg = decode(payload, INFO, ri.MAX_INFO_BYTES)  # kept whole: a real driver's distortion and ROI too
        with self._cond:
            self._info = msg

    def _on_image(self, payload: bytes) -> None:
        self._offer("raw", payload)

    def _on_compressed(self, payload: bytes) -> None:
        self._offer("compressed", payload)

    def _offer(self, kind: str, payload: bytes) -> None:
        stamp = _peek_stamp(payload)
        with self._cond:
            if self._kind is None:
                self._kind = kind
                log.info("camera recording: recording the robot's %s images", kind)
            if kind != self._kind:
                self.other_kind += 1
                return
            self.received += 1
            if stamp is not None and not self._due(stamp):
                self.thinned += 1
                return
            if self._slot is not None:
                self.dropped += 1
            self._slot = (stamp, kind, payload)
            self._cond.notify()

    def _due(self, stamp: float) -> bool:
        """Whether a frame at ``stamp`` [s] (robot clock) is one to record."""
        return stamp - self._last_kept >= self.period or stamp < self._last_kept - RESET_S

    # ------------------------------------------------------------------ the worker
    def _run(self) -> None:
        while True:
            with self._cond:
                while self._slot is None and not self._closed:
                    self._cond.wait()
                if self._closed:
                    return
                item, self._slot = self._slot, None
                if item is None:
                    continue
                stamp, kind, payload = item
                if stamp is not None and not self._due(stamp):  # the frame before it was recorded meanwhile
                    self.thinned += 1
                    continue
            try:
                self._record(kind, payload)
            except Exception as e:  # a frame that cannot be recorded must not end the recording's images
                self.rejects.reject("internal", f"{type(e).__name__}: {e}")

    def _record(self, kind: str, payload: bytes) -> None:
        frame = ri.parse_image(payload) if kind == "raw" else ri.parse_compressed(payload)
        if isinstance(frame, Rejected):
            self.rejects.reject(frame.key, frame.reason)
            return
        with self._cond:
            info = self._info
        if info is None:
            self.rejects.reject("no_camera_info", "image before any valid CameraInfo")
            return
        if (info.width, info.height) != frame.size:
            self.rejects.reject("inconsistent", f"image of {frame.size} px, CameraInfo of {info.width}x{info.height}")
            return
        offset = self._offset()
        if offset is None:
            self.rejects.reject("no_clock", "image before any joint state: its stamp has no recording time")
            return
        stamp = frame.stamp + offset
        if kind == "raw":
            rgb = frame.image if frame.image.ndim == 3 else cv2.cvtColor(frame.image, cv2.COLOR_GRAY2RGB)
            image = ri.encode_compressed(stamp, frame.frame_id, rgb, self.quality)
        else:  # the robot's own bytes (parse_compressed has checked they decode): restamped only
            msg = decode(payload, COMPRESSED, ri.MAX_IMAGE_BYTES)
            image = _ser(dataclasses.replace(msg, header=_header(stamp, frame.frame_id)), COMPRESSED)
        info_cdr = _ser(dataclasses.replace(info, header=_header(stamp, frame.frame_id)), INFO)
        with self._cond:
            self._last_kept = frame.stamp
        t = time.time()
        self.sink.write_ros(self.info_topic, INFO, info_cdr, t)
        self.sink.write_ros(self.image_topic, COMPRESSED, image, t)
        with self._cond:
            self.written += 1

    # ------------------------------------------------------------------ end
    def stats(self) -> dict[str, Any]:
        """Frames received, thinned out, dropped (replaced while the worker was busy), written, rejected, and
        of the kind not recorded (``other_kind``, counted only when there are some)."""
        with self._cond:
            out = {"received": self.received, "thinned": self.thinned, "dropped": self.dropped,
                   "written": self.written, "rejected": self.rejects.counts()}
            if self.other_kind:
                out["other_kind"] = self.other_kind
            return out

    def close(self) -> None:
        """Stop taking frames (undeclare, end the worker); the sink stays open (its owner closes it)."""
        for s in self._subs:
            s.undeclare()
        self._subs = []
        with self._cond:
            self._closed = True
            self._cond.notify()
        self._worker.join(timeout=2.0)
        log.info("camera recording: %s", self.stats())



class LocalFrameTap:
    """A local camera's frames into ``sink`` (module docstring), thinned to ``rate_hz`` of the wall clock;
    called by :class:`~rlgp_exec.executive.local_camera.LocalCamera` with each frame it hands on. It encodes
    in the capture thread: at a few frames a second, a few ms each."""

    def __init__(self, sink: RecordSink, keys: KeyMap, K: Any, size: tuple[int, int],
                 rate_hz: float = DEFAULT_RATE_HZ, quality: int = JPEG_QUALITY) -> None:
        if not (math.isfinite(rate_hz) and 0 < rate_hz <= 30):
            raise ValueError(f"camera recording rate must be in (0, 30] Hz, got {rate_hz!r}")
        self.sink, self.K, self.size = sink, K, size
        self.period, self.quality = 1.0 / rate_hz, int(quality)
        self.image_topic, self.info_topic = camera_topics(keys)
        self.thinned = self.written = self.failed = 0
        self._last = -math.inf  # [s] wall: the last frame recorded

    def __call__(self, frame: ri.ImageFrame) -> None:
        t = time.time()
        if t - self._last < self.period:
            self.thinned += 1
            return
        self._last = t
        try:
            image = ri.encode_compressed(t, frame.frame_id, frame.image, self.quality)
            info = ri.encode_camera_info(t, frame.frame_id, self.size[0], self.size[1], self.K)
            self.sink.write_ros(self.info_topic, INFO, info, t)
            self.sink.write_ros(self.image_topic, COMPRESSED, image, t)
        except Exception as e:  # a frame that cannot be recorded must not end the camera's feed
            self.failed += 1
            if self.failed == 1:
                log.warning("camera recording: a local camera frame not recorded: %s: %s", type(e).__name__, e)
            return
        self.written += 1

    def stats(self) -> dict[str, int]:
        return {"thinned": self.thinned, "written": self.written, "failed": self.failed}
