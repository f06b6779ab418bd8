"""A local camera for lab demos: an OpenCV device or a video file, with its calibration file, feeding the
camera object source in place of the robot's camera topics.

    rlgp-exec run SCENE --backend zenoh --camera /dev/video0 --calibration cam.yaml

The camera is taken to be mounted where the robot's head camera is (its optical frame), so the robot's
joint states still place it in the world. A local capture carries no robot-clock stamp: each frame is
stamped with the latest joint state's stamp when it is read, which is right to within the capture's
own latency (tens of ms on a USB camera; keep the head still while it looks). Frames are undistorted
with the calibration (:class:`~rlgp_exec.perception.calibration.Undistorter`) before detection.

In a recording (and the live view) its frames are the head camera's: JPEG CompressedImage and CameraInfo
on the robot's camera topics (:class:`~rlgp_exec.executive.camera_record.LocalFrameTap`).

A device that stops delivering is reopened every second, and said so once; a video file ends the feed
at its end (the last poses stay until they are stale).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from pathlib import Path

import cv2
import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.camera_source import CameraObjects
from rlgp_exec.hal import ros_image as ri
from rlgp_exec.perception.calibration import Undistorter, load_calibration

__all__ = ["LocalCamera", "check_source", "open_capture"]

log = logging.getLogger(__name__)

REOPEN_S = 1.0  # [s] between attempts to reopen a device that stopped delivering


def _is_device(source: str) -> bool:
    return source.isdigit() or source.startswith("/dev/video")


def check_source(source: str) -> None:
    """RlgpError unless ``source`` names a device (``/dev/videoN`` that exists, or ``N``) or a video file."""
    if source.isdigit():
        return
    if not Path(source).exists():
        raise RlgpError(f"--camera {source}: no such device or video file (a device is /dev/videoN or N)")


def open_capture(source: str) -> cv2.VideoCapture:
    """An open ``cv2.VideoCapture`` of a device (``/dev/video0`` or ``0``) or a video file; RlgpError if not."""
    check_source(source)
    cap = cv2.VideoCapture(int(source) if source.isdigit() else source)
    if not cap.isOpened():
        raise RlgpError(f"--camera {source}: OpenCV cannot open it (no permission, busy, or no codec)")
    return cap


class LocalCamera:
    """Read ``source`` in a thread, undistort each frame and hand it to ``objects`` (its ``submit``)."""

    def __init__(self, source: str, calibration: str | Path, objects: CameraObjects, rate_hz: float = 15.0) -> None:
        self.source, self.objects = source, objects
        self.undistort = Undistorter(load_calibration(calibration))
        cal = self.undistort.calibration
        self.period = 1.0 / rate_hz
        self.device = _is_device(source)
        self._cap = open_capture(source)
        c = self.undistort.intrinsics
        objects.set_camera_model(ri.CameraModel(0.0, objects.camera_frame, c.width, c.height, c.K))
        self.on_frame: Callable[[ri.ImageFrame], None] | None = None  # a recording's tap (LocalFrameTap)
        self.frames = 0
        self.failed_reads = 0
        self.size_mismatches = 0
        self.ended = threading.Event()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="local-camera", daemon=True)
        log.info("local camera %s: %dx%d, calibration %s", source, cal.width, cal.height, calibration)

    def start(self) -> LocalCamera:
        self._thread.start()
        return self

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=2.0)
        self._cap.release()

    def _frame(self, bgr: np.ndarray) -> bool:
        latest = self.objects.history.latest()
        if latest is None:  # no robot state yet: no pose for the camera
            return False
        try:
            rgb = self.undistort(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB))
        except Exception as e:  # a frame of the wrong size (another device, a changed mode): dropped, told once
            self.size_mismatches += 1
            if self.size_mismatches == 1:
                log.warning("local camera %s: frame dropped: %s", self.source, e)
            return False
        frame = ri.ImageFrame(latest[0], self.objects.camera_frame, rgb)
        self.objects.submit(frame)
        self.frames += 1
        tap = self.on_frame  # read once: the run's end unsets it from another thread
        if tap is not None:
            tap(frame)
        return True

    def _run(self) -> None:
        nxt = time.perf_counter()
        while not self._stop.is_set():
            ok, bgr = self._cap.read()
            if not ok or bgr is None:
                if not self.device:
                    log.info("local camera %s: the video ended after %d frames", self.source, self.frames)
                    self.ended.set()
                    return
                self.failed_reads += 1
                if self.failed_reads == 1:
                    log.warning("local camera %s: no frame; reopening every %.0f s", self.source, REOPEN_S)
                self._cap.release()
                if self._stop.wait(REOPEN_S):
                    return
                self._cap = cv2.VideoCapture(int(self.source) if self.source.isdigit() else self.source)
                continue
            try:
                self._frame(bgr)
            except Exception:  # a bug on one frame must not end the camera
                log.exception("local camera %s: frame failed", self.source)
            if not self.device:  # a file reads as fast as it decodes: play it at the camera's rate
                nxt += self.period
                self._stop.wait(max(0.0, nxt - time.perf_counter()))
