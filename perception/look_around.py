"""Look-around: point the head where a not-yet-seen object could be, until it is seen.

Where to look, in order: the object's pose in the scene file (or its last estimate), then the
surfaces it could rest on (fixture tops, cabinet tops, open drawers), nearest first, each at its
centre and, for surfaces wider than the camera sees, its quarters. For each view the head joints are
solved to put the point on the optical axis, with the robot's ``[lookout]`` joints (a raised lift)
for a steeper view; views the head cannot reach are skipped. Objects still unseen can then be looked
for from *vantage* base poses around their candidate points (``feasible(q)`` says which base poses
are collision-free): on a robot the executive drives there; in simulation the capture teleports.
``capture(q)`` is whatever takes a picture with the robot at ``q`` — the HAL on a robot, a renderer
in simulation — and returns (image, T_world_camera, stamp).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from rlgp_exec.perception.camera import FloatArray
from rlgp_exec.perception.pipeline import Perception, PerceptionReport
from rlgp_exec.robot.head import look_at_q, pointing_error
from rlgp_exec.robot.model import RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import support_surfaces

__all__ = ["Capture", "LookAroundResult", "candidate_points", "look_around", "lookout_q", "vantage_bases"]

log = logging.getLogger(__name__)
Capture = Callable[[FloatArray], tuple[np.ndarray, FloatArray, float]]
MAX_POINTING_ERROR = math.radians(5.0)
VANTAGE_RADII = (0.6, 0.8, 1.0)  # [m] from a point to a vantage base pose, tried in this order


def lookout_q(model: RobotModel, q: FloatArray) -> FloatArray:
    """``q`` with the robot's ``[lookout]`` joint overrides (within limits)."""
    q = np.asarray(q, float).copy()
    for joint, value in model.config.lookout.items():
        i = model.index(joint)
        q[i] = float(np.clip(value, model.limits.lower[i], model.limits.upper[i]))
    return q


def vantage_bases(
    point: FloatArray, base_xy: FloatArray, radii: Sequence[float] = VANTAGE_RADII, n: int = 12
) -> list[FloatArray]:
    """Base poses (x, y, yaw) on circles around ``point``, facing it: the nearest circle first (a
    point 0.3 m inside a large table has no free base 0.6 m from it), nearest to ``base_xy`` within it."""
    out = []
    for radius in radii:
        ring = []
        for a in np.linspace(0.0, 2 * math.pi, n, endpoint=False):
            xy = np.asarray(point[:2], float) + radius * np.array([math.cos(a), math.sin(a)])
            ring.append(np.array([xy[0], xy[1], math.atan2(point[1] - xy[1], point[0] - xy[0])]))
        out += sorted(ring, key=lambda b: float(np.linalg.norm(b[:2] - base_xy)))
    return out


@dataclass(frozen=True)
class LookAroundResult:
    seen: frozenset[str]
    missing: frozenset[str]
    views: tuple[FloatArray, ...]  # the head configurations q used, in order
    reports: tuple[PerceptionReport, ...]


def candidate_points(scene: Scene, name: str, start: FloatArray | None = None) -> list[FloatArray]:
    """World points (3,) worth looking at for object ``name``, most likely first."""
    obj = scene.object(name)
    first = np.asarray(obj.pose[:3], float) if start is None else np.asarray(start, float)
    pts = [first]
    surfaces = sorted(support_surfaces(scene, exclude=name), key=lambda s: float(np.linalg.norm(s.T[:3, 3] - first)))
    for s in surfaces:
        pts.append(s.T[:3, 3].copy())
        if max(s.size) > 0.6:
            for dx in (-0.25, 0.25):
                for dy in (-0.25, 0.25):
                    pts.append((s.T @ np.array([dx * s.size[0], dy * s.size[1], 0.0, 1.0]))[:3])
    return pts


def look_around(
    perception: Perception,
    model: RobotModel,
    q: FloatArray,
    scene: Scene,
    names: Sequence[str],
    capture: Capture,
    max_views: int = 16,
    feasible: Callable[[FloatArray], bool] | None = None,
    head_views_per_object: int = 3,
    min_observations: int = 2,
    target_std_m: float = 0.006,
) -> LookAroundResult:
    """Take pictures until every object in ``names`` has been seen in ``min_observations`` views and its
    fused estimate's position error figure is at most ``target_std_m``, or ``max_views`` run out.
    Head-only views from the current base first; then, with ``feasible``, from vantage base poses."""
    wanted = set(names)
    views: list[FloatArray] = []
    reports: list[PerceptionReport] = []
    seen: set[str] = set()
    counts: dict[str, int] = {}
    q_look = lookout_q(model, q)
    base = [model.index(j) for j in ("base_x", "base_y", "base_yaw")]

    def points(n: str) -> list[FloatArray]:
        est = perception.tracker.estimate(n)
        return candidate_points(scene, n, None if est is None else est.T_world_object[:3, 3])

    def view(q_robot: FloatArray, point: FloatArray) -> None:
        q_view = look_at_q(model, q_robot, point)
        if pointing_error(model, q_view, point) > MAX_POINTING_ERROR:
            log.debug("cannot point the head at %s", np.round(point, 3))
            return
        if views and np.allclose(q_view, views[-1], atol=1e-3):
            return
        image, T_world_camera, stamp = capture(q_view)
        rep = perception.process(image, T_world_camera, stamp)
        views.append(q_view)
        reports.append(rep)
        for n in set(rep.updated) & wanted:
            counts[n] = counts.get(n, 0) + 1
            est = perception.tracker.estimate(n)
            if counts[n] >= min_observations and est is not None and est.pos_std_m <= target_std_m:
                seen.add(n)

    for n in sorted(wanted):
        for point in points(n)[:head_views_per_object]:
            if len(views) >= max_views or n in seen:
                break
            view(q_look, point)
    if feasible is not None:
        for n in sorted(wanted - seen):
            for point in points(n)[:1]:
                for b in vantage_bases(point, q_look[base[:2]], n=16):
                    if len(views) >= max_views or n in seen:
                        break
                    q_b = q_look.copy()
                    q_b[base] = b
                    if feasible(q_b):
                        view(q_b, point)
    missing = wanted - seen
    if missing:
        log.warning("look-around: %s not seen in %d views", sorted(missing), len(views))
    return LookAroundResult(frozenset(seen), frozenset(missing), tuple(views), tuple(reports))
