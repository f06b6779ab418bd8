"""Object pose estimates from tag observations: fusion of several tags, a temporal filter, staleness.

Each observation gives T_world_object = T_world_camera T_camera_tag T_object_tag^-1 with a 1-sigma
position and rotation error. Observations of one object in one image are fused by inverse-variance
weighting (positions; rotations by a weighted quaternion mean). Over time each object carries a
constant-position filter: the variance grows by ``process_std`` [m/sqrt(s)] and each fused
measurement updates it with a Kalman gain; rotation is blended with the same gain. A measurement
further than ``gate_sigma`` sigmas (and ``gate_min_m``) from the estimate is taken as the object having
been moved: the estimate restarts from it — with ``confirm`` > 1, once that many measurements in a row
agree on the new place (one poor view, a flipped PnP solution at a grazing angle, does not move an
object; until then the jump is held aside and the estimate kept). An estimate older than ``max_age_s``
is stale.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from rlgp_exec.perception.camera import FloatArray

__all__ = ["ObjectEstimate", "ObjectTracker", "Observation"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Observation:
    """One tag's evidence for an object's pose at ``stamp`` [s]."""

    object: str
    tag_id: int
    T_world_object: FloatArray
    pos_std_m: float
    rot_std_rad: float
    stamp: float


@dataclass(frozen=True)
class ObjectEstimate:
    object: str
    T_world_object: FloatArray
    pos_std_m: float
    rot_std_rad: float
    stamp: float  # time of the last measurement [s]
    n_updates: int
    tags: tuple[int, ...]  # the tags of the last update

    def age(self, now: float) -> float:
        return now - self.stamp


def _fuse(obs: list[Observation]) -> tuple[FloatArray, float, float]:
    w = np.array([1.0 / o.pos_std_m**2 for o in obs])
    p = np.sum([wi * o.T_world_object[:3, 3] for wi, o in zip(w, obs, strict=True)], axis=0) / w.sum()
    wr = np.array([1.0 / o.rot_std_rad**2 for o in obs])
    R = Rotation.from_matrix(np.stack([o.T_world_object[:3, :3] for o in obs])).mean(weights=wr)
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = R.as_matrix(), p
    return T, float(1.0 / math.sqrt(w.sum())), float(1.0 / math.sqrt(wr.sum()))


class ObjectTracker:
    def __init__(
        self,
        max_age_s: float = 2.0,
        process_std: float = 0.002,
        gate_sigma: float = 6.0,
        gate_min_m: float = 0.03,
        confirm: int = 1,
    ) -> None:
        self.max_age_s, self.process_std = max_age_s, process_std
        self.gate_sigma, self.gate_min_m = gate_sigma, gate_min_m
        self.confirm = max(1, int(confirm))
        self._est: dict[str, ObjectEstimate] = {}
        self._jumps: dict[str, list[ObjectEstimate]] = {}  # measurements away from the estimate, in a row

    def update(self, observations: list[Observation]) -> list[str]:
        """Fold in one image's observations; returns the objects updated."""
        by_obj: dict[str, list[Observation]] = {}
        for o in observations:
            by_obj.setdefault(o.object, []).append(o)
        for name, obs in by_obj.items():
            T_m, ps_m, rs_m = _fuse(obs)
            stamp = max(o.stamp for o in obs)
            tags = tuple(sorted(o.tag_id for o in obs))
            prev = self._est.get(name)
            if prev is None or stamp - prev.stamp > self.max_age_s:
                self._est[name] = ObjectEstimate(name, T_m, ps_m, rs_m, stamp, 1, tags)
                continue
            dt = max(stamp - prev.stamp, 0.0)
            var = prev.pos_std_m**2 + self.process_std**2 * dt
            jump = float(np.linalg.norm(T_m[:3, 3] - prev.T_world_object[:3, 3]))
            if jump > max(self.gate_sigma * math.sqrt(var + ps_m**2), self.gate_min_m):
                held = self._jumps.setdefault(name, [])
                first = held[0].T_world_object[:3, 3] if held else T_m[:3, 3]
                if held and np.linalg.norm(T_m[:3, 3] - first) > self.gate_min_m:
                    held.clear()  # the jumps disagree among themselves: noise, not a move
                held.append(ObjectEstimate(name, T_m, ps_m, rs_m, stamp, 1, tags))
                if len(held) >= self.confirm:
                    log.info("%s moved %.3f m since the last estimate: restarting its filter", name, jump)
                    self._est[name] = held[-1]
                    self._jumps.pop(name, None)
                continue
            self._jumps.pop(name, None)
            k = var / (var + ps_m**2)
            rvar = prev.rot_std_rad**2 + (self.process_std * 10.0) ** 2 * dt  # [rad^2]: rotation drifts too
            kr = rvar / (rvar + rs_m**2)
            T = np.eye(4)
            T[:3, 3] = prev.T_world_object[:3, 3] + k * (T_m[:3, 3] - prev.T_world_object[:3, 3])
            r0, r1 = Rotation.from_matrix(prev.T_world_object[:3, :3]), Rotation.from_matrix(T_m[:3, :3])
            T[:3, :3] = (r0 * Rotation.from_rotvec(kr * (r0.inv() * r1).as_rotvec())).as_matrix()
            self._est[name] = replace(
                prev,
                T_world_object=T,
                pos_std_m=math.sqrt((1 - k) * var),
                rot_std_rad=math.sqrt((1 - kr) * rvar),
                stamp=stamp,
                n_updates=prev.n_updates + 1,
                tags=tags,
            )
        return sorted(by_obj)

    def estimate(self, name: str) -> ObjectEstimate | None:
        return self._est.get(name)

    def estimates(self) -> dict[str, ObjectEstimate]:
        return dict(self._est)

    def is_stale(self, name: str, now: float) -> bool:
        e = self._est.get(name)
        return e is None or e.age(now) > self.max_age_s

    def put(self, estimate: ObjectEstimate) -> None:
        """Set an object's estimate from other evidence (the robot put it down where its hand was)."""
        self._est[estimate.object] = estimate
        self._jumps.pop(estimate.object, None)

    def forget(self, name: str) -> None:
        self._est.pop(name, None)
        self._jumps.pop(name, None)
