"""The pose of a held object in the hand, as the graph-NLP's variables parameterise it."""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import NDArray

__all__ = ["rel_pose"]

FloatArray = NDArray[np.float64]


def rel_pose(r: ca.SX, upright: FloatArray) -> ca.SX:
    """T_tool_obj of the held pose r = [d, s, psi, theta]: the object's centre d below the tool point
    along the object's axis, shifted s along the fingers (tool y), turned psi about its own axis and
    tilted theta about the fingers' axis (a leaning hand reaches further across a table)."""
    c, s = ca.cos(r[2]), ca.sin(r[2])
    Rz = ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
    ct, st = ca.cos(r[3]), ca.sin(r[3])
    Ry = ca.vertcat(ca.horzcat(ct, 0, st), ca.horzcat(0, 1, 0), ca.horzcat(-st, 0, ct))
    R = Ry @ ca.DM(upright) @ Rz
    T = ca.SX.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -r[0] * R[:, 2] + r[1] * ca.DM([0.0, 1.0, 0.0])
    return T
