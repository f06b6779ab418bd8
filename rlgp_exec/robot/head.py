"""Pointing the head camera: the head joints that put a world point on the camera's optical axis."""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from rlgp_exec.robot.model import FloatArray, RobotModel

__all__ = ["look_at_q", "pointing_error"]


def pointing_error(model: RobotModel, q: FloatArray, target_world: FloatArray) -> float:
    """Angle [rad] between the camera's optical axis and the direction to ``target_world`` (3,)."""
    T = model.fk(q, model.config.frames["camera"])
    d = np.asarray(target_world, float) - T[:3, 3]
    c = float(T[:3, 2] @ d / max(float(np.linalg.norm(d)), 1e-12))
    return float(np.arccos(np.clip(c, -1.0, 1.0)))


def look_at_q(model: RobotModel, q: FloatArray, target_world: FloatArray) -> FloatArray:
    """``q`` with the head joints (group "head") set to look at ``target_world``, within their limits;
    the rest of ``q`` unchanged. Check :func:`pointing_error` when the target may be out of reach."""
    idx = np.array(model.group("head"))
    lo, hi = model.limits.lower[idx], model.limits.upper[idx]
    frame = model.config.frames["camera"]
    target = np.asarray(target_world, float)
    q = np.asarray(q, float).copy()

    def residual(x: FloatArray) -> FloatArray:
        q[idx] = x
        T = model.fk(q, frame)
        d = target - T[:3, 3]
        d = d / max(float(np.linalg.norm(d)), 1e-12)
        return T[:3, :3].T @ d - np.array([0.0, 0.0, 1.0])  # the direction in the optical frame vs its z axis

    x0 = np.clip(q[idx], lo, hi)
    sol = least_squares(residual, x0, bounds=(lo, hi), xtol=1e-10, ftol=1e-10)
    q[idx] = sol.x
    return q
