"""Head views: a collision-free head posture to look at a point, and how large a tag there would look.

A view puts the point on the camera's optical axis (``look_at_q``). When that posture collides — on
the HSR with its lift down, the head tilted below ~25 deg meets the base — the head pans all the way
and tilts only as far as it stays free (else both joints stop short), and the view counts while the
point is still well inside the image.
The move itself (a straight line in the head joints from where the head is) is checked at samples
along the way. Collisions are the planners' checker's: the robot against itself and the fixtures.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rlgp_exec.perception.camera import CameraIntrinsics, FloatArray
from rlgp_exec.reach.checker import WorldChecker
from rlgp_exec.robot.head import look_at_q, pointing_error
from rlgp_exec.robot.model import RobotModel
from rlgp_exec.scene import Scene

__all__ = ["MAX_POINTING_ERROR", "HeadView", "HeadViews"]

MAX_POINTING_ERROR = math.radians(5.0)  # the head cannot put the point nearer the optical axis: no view
PATH_SAMPLES = 8  # postures checked along a head move, its end included
BISECTIONS = 7  # halvings of the way towards a colliding view (1/128 of the head's turn)
IN_FRAME_MARGIN = 0.15  # a shortened view counts while the point is this fraction of the image inside it


@dataclass(frozen=True)
class HeadView:
    """The configuration (nq,) to command for a view, and whether it stops short of the point (the
    posture pointing straight at it collides)."""

    q: FloatArray
    shortened: bool


class HeadViews:
    """Head postures for looking at world points, checked for collisions with the robot and ``scene``'s
    fixtures (objects and drawers as the scene file has them closed)."""

    def __init__(self, model: RobotModel, scene: Scene, camera: CameraIntrinsics) -> None:
        self.model, self.camera = model, camera
        self.head = list(model.group("head"))
        self.camera_frame = model.config.frames["camera"]
        self._checker = WorldChecker(scene, model.manipulator().group)

    def collides(self, q: FloatArray) -> bool:
        """True when ``q`` penetrates the robot itself or a fixture."""
        return bool(self._checker.penetrates(np.asarray(q, float)))

    def _path_free(self, q0: FloatArray, q1: FloatArray) -> bool:
        return not any(self.collides(q0 + s * (q1 - q0)) for s in np.linspace(0.0, 1.0, PATH_SAMPLES + 1)[1:])

    def in_frame(self, q: FloatArray, point: FloatArray, margin: float = IN_FRAME_MARGIN) -> bool:
        """Whether ``point`` (3,) projects into the image at ``q``, ``margin`` of its size from the edges."""
        T = self.model.fk(q, self.camera_frame)
        p = T[:3, :3].T @ (np.asarray(point, float) - T[:3, 3])
        if p[2] <= 0.0:
            return False
        u, v = self.camera.project(p)[0]
        w, h = self.camera.width, self.camera.height
        return bool(margin * w <= u <= (1 - margin) * w and margin * h <= v <= (1 - margin) * h)

    def view(self, q: FloatArray, point: FloatArray) -> HeadView | str:
        """The view of ``point`` (3,) from ``q`` (the measured configuration), or why there is none."""
        q = np.asarray(q, float)
        q_view = look_at_q(self.model, q, point)
        if pointing_error(self.model, q_view, point) > MAX_POINTING_ERROR:
            return "the head cannot point there"
        if self._path_free(q, q_view):
            return HeadView(q_view, False)
        # the head turned all the way but tilted only as far as it stays free, else both joints shortened
        pan_first = np.zeros(self.model.nq, dtype=bool)
        pan_first[self.head[1:]] = True
        for moving in (pan_first, np.ones(self.model.nq, dtype=bool)):
            start = np.where(moving, q, q_view)
            if not self._path_free(q, start):
                continue
            lo, hi = 0.0, 1.0  # the free part of the way from ``start`` towards the view
            for _ in range(BISECTIONS):
                mid = 0.5 * (lo + hi)
                if self._path_free(q, start + mid * (q_view - start)):
                    lo = mid
                else:
                    hi = mid
            q_short = start + lo * (q_view - start)
            if self.in_frame(q_short, point):
                return HeadView(q_short, True)
        names = [self.model.joint_names[i] for i in self.head]
        return f"the head posture looking there collides ({names} = {np.round(q_view[self.head], 2).tolist()})"

    def tag_side_px(self, q: FloatArray, point: FloatArray, size_m: float) -> float:
        """The expected shortest side [px] of a ``size_m`` tag at ``point`` facing up (as on a standing
        object) in the image at ``q``: its size across the distance, foreshortened by the angle."""
        T = self.model.fk(q, self.camera_frame)
        ray = T[:3, 3] - np.asarray(point, float)
        d = max(float(np.linalg.norm(ray)), 1e-6)
        return size_m * self.camera.fx / d * abs(float(ray[2])) / d
