"""Pinhole camera models: intrinsics per robot, extrinsics from the robot's FK.

Frames: the optical frame has z forward, x right, y down (OpenCV). ``T_world_camera`` maps optical
-frame points to the world. Pixel (u, v) = (fx x/z + cx, fy y/z + cy), u to the right, v down.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rlgp_exec.errors import RlgpError

__all__ = ["CAMERAS", "CameraIntrinsics", "PerceptionError", "camera_for_robot"]

FloatArray = NDArray[np.float64]


class PerceptionError(RlgpError):
    """Bad input to perception: an image, intrinsics, a tag registry."""


@dataclass(frozen=True)
class CameraIntrinsics:
    """An undistorted pinhole camera: image size [px], focal lengths and principal point [px]."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float

    def __post_init__(self) -> None:
        if not (self.width >= 16 and self.height >= 16):
            raise PerceptionError(f"camera image size {self.width}x{self.height} too small (min 16x16)")
        vals = (self.fx, self.fy, self.cx, self.cy)
        if not all(math.isfinite(v) for v in vals) or self.fx <= 0 or self.fy <= 0:
            raise PerceptionError(f"camera intrinsics need finite fx, fy > 0, got fx={self.fx}, fy={self.fy}")

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> CameraIntrinsics:
        """Square pixels, principal point at the image centre, horizontal field of view [deg]."""
        if not (0.0 < hfov_deg < 180.0):
            raise PerceptionError(f"horizontal field of view must be in (0, 180) deg, got {hfov_deg}")
        f = (width / 2.0) / math.tan(math.radians(hfov_deg) / 2.0)
        return cls(width, height, f, f, (width - 1) / 2.0, (height - 1) / 2.0)

    @classmethod
    def parse(cls, text: str) -> CameraIntrinsics:
        """From "W,H,fx,fy,cx,cy" (the CLI's --intrinsics)."""
        parts = text.split(",")
        if len(parts) != 6:
            raise PerceptionError(f"intrinsics must be 'W,H,fx,fy,cx,cy' (6 numbers), got {text!r}")
        try:
            w, h = int(parts[0]), int(parts[1])
            fx, fy, cx, cy = (float(x) for x in parts[2:])
        except ValueError:
            raise PerceptionError(f"intrinsics must be numbers 'W,H,fx,fy,cx,cy', got {text!r}") from None
        return cls(w, h, fx, fy, cx, cy)

    @property
    def K(self) -> FloatArray:
        """The (3, 3) camera matrix."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def hfov_deg(self) -> float:
        return math.degrees(2.0 * math.atan(self.width / (2.0 * self.fx)))

    def project(self, p_camera: FloatArray) -> FloatArray:
        """Pixels (N, 2) of optical-frame points (N, 3) (z > 0)."""
        p = np.atleast_2d(np.asarray(p_camera, float))
        return np.stack([self.fx * p[:, 0] / p[:, 2] + self.cx, self.fy * p[:, 1] / p[:, 2] + self.cy], axis=1)

    def gl_projection(self, near: float = 0.02, far: float = 20.0) -> list[float]:
        """The column-major OpenGL projection matrix PyBullet needs to render exactly this camera
        (pixel centres at integer coordinates, v down)."""
        w, h = self.width, self.height
        # NDC x = (2 (u + 0.5) / w - 1), y = -(2 (v + 0.5) / h - 1) with u = fx x/z + cx, camera looks along -z (GL)
        P = np.zeros((4, 4))
        P[0, 0] = 2.0 * self.fx / w
        P[1, 1] = 2.0 * self.fy / h
        P[0, 2] = 1.0 - 2.0 * (self.cx + 0.5) / w
        P[1, 2] = 2.0 * (self.cy + 0.5) / h - 1.0
        P[2, 2] = -(far + near) / (far - near)
        P[2, 3] = -2.0 * far * near / (far - near)
        P[3, 2] = -1.0
        return P.T.reshape(-1).tolist()


#: The robots' head cameras. HSR: the head RGB-D sensor's RGB stream (640x480, ~58 deg horizontal).
#: PR2: the narrow stereo camera (640x480, ~55 deg horizontal; the wide one's 90 deg leaves a 4 cm tag
#: ~7 px across at the far side of a table, under the detector's 10 px).
CAMERAS: dict[str, CameraIntrinsics] = {
    "hsr": CameraIntrinsics.from_hfov(640, 480, 58.0),
    "pr2": CameraIntrinsics.from_hfov(640, 480, 55.0),
}


def camera_for_robot(robot: str) -> CameraIntrinsics:
    try:
        return CAMERAS[robot]
    except KeyError:
        raise PerceptionError(f"no camera model for robot {robot!r}; valid: {sorted(CAMERAS)}") from None
