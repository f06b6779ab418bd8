"""A local camera's calibration file, and the undistortion that makes its images pinhole images.

Two formats, as labs have them: OpenCV's (``cv2.FileStorage`` YAML or XML, as written by OpenCV's
calibration sample: ``camera_matrix``, ``distortion_coefficients``, ``image_width``, ``image_height``)
and ROS's ``camera_calibration`` YAML (``camera_matrix: {rows, cols, data}``, the same names otherwise).
The detector's PnP assumes a pinhole camera, so images are undistorted first (:class:`Undistorter`), to
the camera matrix of the undistorted image.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from rlgp_exec.perception.camera import CameraIntrinsics, FloatArray, PerceptionError

__all__ = ["Calibration", "Undistorter", "load_calibration"]

_K_KEYS = ("camera_matrix", "K", "cameraMatrix")
_D_KEYS = ("distortion_coefficients", "D", "dist_coeffs", "distCoeffs")
_W_KEYS = ("image_width", "width")
_H_KEYS = ("image_height", "height")
DIST_SIZES = (0, 4, 5, 8, 12, 14)  # the distortion vectors OpenCV models


@dataclass(frozen=True)
class Calibration:
    """A camera's size [px], camera matrix K (3, 3) and distortion coefficients (N,) (OpenCV's model)."""

    width: int
    height: int
    K: FloatArray
    dist: FloatArray


def _first(fs: cv2.FileStorage, keys: tuple[str, ...]) -> cv2.FileNode | None:
    for k in keys:
        node = fs.getNode(k)
        if not node.empty():
            return node
    return None


def _matrix(node: cv2.FileNode, path: Path, what: str) -> FloatArray:
    if node.isMap():  # ROS: {rows, cols, data}
        data = node.getNode("data")
        if data.empty() or not data.isSeq():
            raise PerceptionError(f"{path}: {what} has no 'data' list")
        vals = [data.at(i).real() for i in range(data.size())]
        rows, cols = int(node.getNode("rows").real() or 0), int(node.getNode("cols").real() or 0)
        arr = np.asarray(vals, float)
        if rows * cols == arr.size and rows > 0:
            arr = arr.reshape(rows, cols)
        return arr
    mat = node.mat()  # OpenCV: !!opencv-matrix
    if mat is None:
        if node.isSeq():
            return np.asarray([node.at(i).real() for i in range(node.size())], float)
        raise PerceptionError(f"{path}: {what} is not a matrix")
    return np.asarray(mat, float)


def load_calibration(path: str | Path) -> Calibration:
    """Read an OpenCV or ROS calibration file; PerceptionError naming the file and what is wrong."""
    p = Path(path)
    if not p.is_file():
        raise PerceptionError(f"calibration file {p} does not exist")
    try:
        fs = cv2.FileStorage(str(p), cv2.FILE_STORAGE_READ)
    except (cv2.error, SystemError) as e:  # OpenCV's parser raises either on a malformed file
        why = str(getattr(e, "msg", e) or e.__cause__).strip()
        raise PerceptionError(f"{p}: not an OpenCV/ROS calibration file (YAML or XML): {why}") from e
    try:
        if not fs.isOpened():
            raise PerceptionError(f"{p}: cannot be read as YAML or XML")
        nodes = {n: _first(fs, keys) for n, keys in (("K", _K_KEYS), ("D", _D_KEYS), ("W", _W_KEYS), ("H", _H_KEYS))}
        missing = [keys[0] for n, keys in (("K", _K_KEYS), ("W", _W_KEYS), ("H", _H_KEYS)) if nodes[n] is None]
        if missing:
            raise PerceptionError(f"{p}: missing {', '.join(missing)} (an OpenCV or ROS camera calibration has them)")
        K = _matrix(nodes["K"], p, "camera_matrix")  # type: ignore[arg-type]
        D = np.zeros(0) if nodes["D"] is None else _matrix(nodes["D"], p, "distortion_coefficients").reshape(-1)
        w, h = nodes["W"].real(), nodes["H"].real()  # type: ignore[union-attr]
    finally:
        fs.release()
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise PerceptionError(f"{p}: camera_matrix must be 3 x 3 and finite, got shape {K.shape}")
    if not (K[0, 0] > 0 and K[1, 1] > 0 and np.allclose(K[2], [0, 0, 1]) and K[1, 0] == 0 and K[0, 1] == 0):
        raise PerceptionError(f"{p}: camera_matrix is not a pinhole camera matrix: {K.round(3).tolist()}")
    if D.size not in DIST_SIZES or not np.all(np.isfinite(D)):
        raise PerceptionError(f"{p}: distortion_coefficients must be {DIST_SIZES[1:]} finite values, got {D.size}")
    if not (w == int(w) and h == int(h) and 16 <= w <= 8192 and 16 <= h <= 8192):
        raise PerceptionError(f"{p}: image_width/image_height must be whole sizes of 16 to 8192 px, got {w} x {h}")
    if not (math.isfinite(K[0, 2]) and 0 <= K[0, 2] <= w and 0 <= K[1, 2] <= h):
        raise PerceptionError(f"{p}: principal point ({K[0, 2]}, {K[1, 2]}) outside the {int(w)} x {int(h)} image")
    return Calibration(int(w), int(h), K.copy(), D.copy())


class Undistorter:
    """Undistort images of ``calibration``'s camera to a pinhole image (all pixels valid, ``alpha`` 0) with
    the camera matrix :attr:`intrinsics`. Without distortion it passes images through."""

    def __init__(self, calibration: Calibration) -> None:
        c = calibration
        self.calibration = c
        self.identity = not np.any(c.dist)
        size = (c.width, c.height)
        if self.identity:
            K_new = c.K
        else:
            K_opt, _ = cv2.getOptimalNewCameraMatrix(c.K, c.dist, size, 0.0, size)
            K_new = np.asarray(K_opt, dtype=np.float64)
            K_new[0, 1] = K_new[1, 0] = 0.0
            self._maps = cv2.initUndistortRectifyMap(c.K, c.dist, None, K_new, size, cv2.CV_16SC2)
        fx, fy, cx, cy = (float(K_new[0, 0]), float(K_new[1, 1]), float(K_new[0, 2]), float(K_new[1, 2]))
        self.intrinsics = CameraIntrinsics(c.width, c.height, fx, fy, cx, cy)

    def __call__(self, image: np.ndarray) -> np.ndarray:
        h, w = image.shape[:2]
        if (w, h) != (self.calibration.width, self.calibration.height):
            raise PerceptionError(
                f"image is {w}x{h}, the calibration is for {self.calibration.width}x{self.calibration.height}"
            )
        if self.identity:
            return image
        return cv2.remap(image, self._maps[0], self._maps[1], cv2.INTER_LINEAR)
