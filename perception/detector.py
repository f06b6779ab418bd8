"""tag36h11 detection in camera images, with sub-pixel corners.

Two detectors behind one interface: OpenCV's ArUco module with its AprilTag dictionary and AprilTag
corner refinement (the default), and ``pupil-apriltags`` (the AprilTag 3 C library) when installed.
``rlgp-exec bench perception`` measures both on the same rendered images.

Bad images raise :class:`PerceptionError` naming the problem (not an ndarray, wrong dtype or
channel count, empty); images that are valid but hold nothing to detect (all one colour) come back
with status ``BLANK``. Tags whose shortest side is under ``min_side_px`` are rejected with a reason:
their corners are too coarse for a pose.
"""

from __future__ import annotations

import enum
import logging
import time
from dataclasses import dataclass

import cv2
import numpy as np

from rlgp_exec.perception.camera import FloatArray, PerceptionError

__all__ = ["DETECTORS", "DetectionResult", "ImageStatus", "TagDetection", "TagDetector", "as_gray"]

log = logging.getLogger(__name__)
DETECTORS = ("opencv", "pupil")


class ImageStatus(enum.Enum):
    OK = "ok"
    BLANK = "blank"  # no contrast at all: all black, all white, one colour


@dataclass(frozen=True)
class TagDetection:
    """One detected tag: corners (4, 2) [px] in the order IPPE_SQUARE expects (the printed tag's
    top-left, top-right, bottom-right, bottom-left), and its shortest side [px]."""

    tag_id: int
    corners: FloatArray
    side_px: float


@dataclass(frozen=True)
class DetectionResult:
    status: ImageStatus
    detections: tuple[TagDetection, ...]
    rejected: tuple[tuple[int, str], ...]  # (tag id, reason)
    detect_ms: float


def as_gray(image: object) -> np.ndarray:
    """A (H, W) uint8 view of an image: (H, W), (H, W, 1), (H, W, 3) RGB or (H, W, 4) RGBA uint8."""
    if not isinstance(image, np.ndarray):
        raise PerceptionError(f"image must be a numpy array, got {type(image).__name__}")
    if image.dtype != np.uint8:
        raise PerceptionError(f"image dtype must be uint8, got {image.dtype}")
    if image.size == 0:
        raise PerceptionError(f"image is empty (shape {image.shape})")
    if image.ndim == 2:
        return image
    if image.ndim == 3 and image.shape[2] in (1, 3, 4):
        if image.shape[2] == 1:
            return image[:, :, 0]
        code = cv2.COLOR_RGB2GRAY if image.shape[2] == 3 else cv2.COLOR_RGBA2GRAY
        return cv2.cvtColor(image, code)
    raise PerceptionError(f"image must be (H, W) or (H, W, 1|3|4), got shape {image.shape}")


class TagDetector:
    """Finds tag36h11 markers; ``backend`` is "opencv" or "pupil"."""

    def __init__(self, backend: str = "opencv", min_side_px: float = 10.0) -> None:
        if backend not in DETECTORS:
            raise PerceptionError(f"unknown tag detector {backend!r}; valid: {list(DETECTORS)}")
        self.backend, self.min_side_px = backend, float(min_side_px)
        if backend == "opencv":
            params = cv2.aruco.DetectorParameters()
            params.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_APRILTAG
            # sample each cell at 8x8 px (default 4x4) with a wider ignored margin when reading the bits:
            # small, far tags (~15 px at 1.5 m with the HSR camera) decode 11 times in 12 instead of 3
            params.perspectiveRemovePixelPerCell = 8
            params.perspectiveRemoveIgnoredMarginPerCell = 0.2
            dictionary = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
            self._cv = cv2.aruco.ArucoDetector(dictionary, params)
        else:
            try:
                # local: optional (the dev extra): the second tag detector
                from pupil_apriltags import Detector
            except ImportError:
                raise PerceptionError(
                    "detector 'pupil' needs the pupil-apriltags package; valid here: ['opencv']"
                ) from None
            self._pupil = Detector(families="tag36h11", nthreads=1, quad_decimate=1.0, refine_edges=True)

    def detect(self, image: object) -> DetectionResult:
        gray = as_gray(image)
        t0 = time.perf_counter()
        if int(gray.max()) - int(gray.min()) < 10:
            return DetectionResult(ImageStatus.BLANK, (), (), (time.perf_counter() - t0) * 1e3)
        raw = self._detect_opencv(gray) if self.backend == "opencv" else self._detect_pupil(gray)
        ms = (time.perf_counter() - t0) * 1e3
        found, rejected = [], []
        for tag_id, corners in raw:
            side = float(np.min(np.linalg.norm(corners - np.roll(corners, -1, axis=0), axis=1)))
            if side < self.min_side_px:
                rejected.append((tag_id, f"tag {tag_id} is {side:.1f} px across, under {self.min_side_px:.0f} px"))
                continue
            found.append(TagDetection(tag_id, corners, side))
        for _, why in rejected:  # a far tag is expected (and in the result), every frame at a camera's rate
            log.debug("tag rejected: %s", why)
        ids = [d.tag_id for d in found]
        dup = {i for i in ids if ids.count(i) > 1}
        if dup:  # the same id twice in one image: cannot tell which is the object's
            twice = [(i, f"tag {i} seen {ids.count(i)} times in one image") for i in sorted(dup)]
            for _, why in twice:
                log.warning("tag rejected: %s", why)
            rejected += twice
            found = [d for d in found if d.tag_id not in dup]
        return DetectionResult(ImageStatus.OK, tuple(found), tuple(rejected), ms)

    def _detect_opencv(self, gray: np.ndarray) -> list[tuple[int, FloatArray]]:
        corners, ids, _ = self._cv.detectMarkers(gray)
        if ids is None:
            return []
        return [(int(i), np.asarray(c, float).reshape(4, 2)) for c, i in zip(corners, ids.reshape(-1), strict=True)]

    def _detect_pupil(self, gray: np.ndarray) -> list[tuple[int, FloatArray]]:
        out = []
        for d in self._pupil.detect(gray):
            # pupil-apriltags: counter-clockwise (in the image) from the bottom-left -> TL, TR, BR, BL
            c = np.asarray(d.corners, float)
            out.append((int(d.tag_id), c[[1, 0, 3, 2]]))
        return out
