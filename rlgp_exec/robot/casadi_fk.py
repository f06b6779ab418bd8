"""Symbolic forward kinematics in CasADi, generated from the pinocchio model.

The ``pin`` wheel ships without ``pinocchio.casadi``, so the chain is rebuilt here from what the
numeric model knows: each joint's placement in its parent (``model.jointPlacements``) and its
constant motion subspace S (6,), read off the joint itself. Every joint of the prepared model has
one degree of freedom, so its motion is ``exp(S q)``: a rotation about S's angular part or a
translation along its linear part. Frames hang off joints with ``frame.placement``.
"""

from __future__ import annotations

from typing import Protocol

import casadi as ca
import numpy as np
import pinocchio as pin

from rlgp_exec.errors import ModelError

__all__ = ["KinematicModel", "build_casadi_fk", "rot_axis_angle"]


class KinematicModel(Protocol):
    """What the CasADi chain is built from (``robot.model.RobotModel``): the pinocchio model and the map
    from planning joints to pinocchio's, q_pin = A q + b."""

    name: str
    pin_model: pin.Model
    nq: int
    A: np.ndarray  # (nq_pin, nq)
    b: np.ndarray  # (nq_pin,)

    def frame_id(self, name: str) -> int: ...

_CACHE: dict[tuple[str, tuple[str, ...]], ca.Function] = {}


def rot_axis_angle(axis: np.ndarray, angle: ca.SX) -> ca.SX:
    """Rotation matrix (3, 3) about a unit ``axis`` by a symbolic ``angle`` (Rodrigues)."""
    k = ca.DM(axis)
    K = ca.skew(k)
    return ca.SX.eye(3) + ca.sin(angle) * K + (1 - ca.cos(angle)) * (K @ K)


def _motion_subspace(model: pin.Model, j: int) -> np.ndarray:
    jm = model.joints[j]
    if jm.nq != 1 or jm.nv != 1:
        raise ModelError(f"joint {model.names[j]!r}: CasADi FK handles 1-DoF joints only (nq={jm.nq})")
    jd = jm.createData()
    jm.calc(jd, np.zeros(model.nq))
    return np.asarray(jd.S).reshape(6)


def _se3(M: pin.SE3) -> ca.SX:
    return ca.SX(ca.DM(M.homogeneous))


def build_casadi_fk(robot: KinematicModel, frames: tuple[str, ...]) -> ca.Function:
    """``Function('fk_<robot>', [q (nq,)], [T_world_frame (4, 4) for each frame])``."""
    key = (robot.name, frames)
    fn = _CACHE.get(key)
    if fn is not None:
        return fn
    model = robot.pin_model
    fids = [robot.frame_id(f) for f in frames]
    q = ca.SX.sym("q", robot.nq)
    q_full = ca.DM(robot.A) @ q + ca.DM(robot.b)

    needed: set[int] = set()
    for fid in fids:
        j = model.frames[fid].parentJoint
        while j > 0:
            needed.add(j)
            j = model.parents[j]

    oMi: dict[int, ca.SX] = {0: ca.SX.eye(4)}
    for j in sorted(needed):  # pinocchio orders joints parents-first
        S = _motion_subspace(model, j)
        v, w = S[:3], S[3:]
        qj = q_full[model.joints[j].idx_q]
        M = ca.SX.eye(4)
        if np.linalg.norm(w) > 1e-12:
            if np.linalg.norm(v) > 1e-12:
                raise ModelError(f"joint {model.names[j]!r}: helical joints are not supported")
            M[:3, :3] = rot_axis_angle(w / np.linalg.norm(w), qj * np.linalg.norm(w))
        else:
            M[:3, 3] = ca.DM(v) * qj
        oMi[j] = oMi[model.parents[j]] @ _se3(model.jointPlacements[j]) @ M

    outs = [oMi[model.frames[fid].parentJoint] @ _se3(model.frames[fid].placement) for fid in fids]
    fn = ca.Function(f"fk_{robot.name}", [q], outs, ["q"], [f"T_world_{f}" for f in frames])
    _CACHE[key] = fn
    return fn
