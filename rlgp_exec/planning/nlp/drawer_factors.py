"""Constraint factors of the drawer actions (CasADi rows for the keyframe NLP).

* :func:`knob_grasp`: the tool at the knob, the hand pointing into the cabinet (horizontal, against the
  opening axis), the fingers closing vertically across the knob's height.
* :func:`follow_prismatic`: the articulated constraint. The hand holds the knob, so the knob's motion
  along the drawer's prismatic axis by ``d`` [m] moves the hand by exactly ``d * axis``; with a
  holonomic base and the arm held still this is the base translation z_k = z_prev + d [ax, ay, 0, ..].
  A whole-body motion could do the same, but the base translation keeps the hand on the axis at every
  instant (not only at the keyframes), which is what the path between the two keyframes needs.
* :func:`drop_above`: a held object upright over the reachable part of an open drawer's interior, its
  bottom between ``z_low`` and ``z_high`` [m].
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows, inside_rectangle
from rlgp_exec.robot.model import FloatArray

__all__ = ["KNOB_STANDOFF", "drop_above", "follow_prismatic", "knob_grasp"]

KNOB_STANDOFF = 0.005  # [m] the tool point sits this far out from the knob's centre, along the axis
HAND_TILT = 0.15  # [rad] the hand's axis may deviate this much from horizontal-into-the-cabinet


def knob_grasp(rs: RobotSymbols, T_world_knob: FloatArray, rows: Rows) -> None:
    """Grasp the knob whose centre frame (x: the opening direction) is ``T_world_knob`` (4, 4)."""
    axis = T_world_knob[:3, 0]
    target = T_world_knob[:3, 3] + KNOB_STANDOFF * axis
    for i in range(3):
        rows.add(rs.tool_pos[i] - float(target[i]), 0.0, 0.0)
    a = rs.tool_axis(rs.manip.approach)
    # no bound at a unit vector's extreme (-1, 1): it holds anyway, and is degenerate (``factors.approach_rows``)
    rows.add(ca.dot(a, ca.DM(axis)), -ca.inf, -float(np.cos(HAND_TILT)))  # pointing into the cabinet
    c = rs.tool_axis(rs.manip.closing)
    rows.add(c[2] * c[2], float(np.cos(HAND_TILT)) ** 2, ca.inf)  # fingers above and below the knob


def follow_prismatic(z_k: ca.SX, z_prev: ca.SX, axis_world: FloatArray, d: float, rows: Rows) -> None:
    """z_k is z_prev with the base moved ``d`` [m] along ``axis_world`` (3,) and nothing else changed."""
    shift = np.zeros(z_k.shape[0])
    shift[:2] = d * np.asarray(axis_world[:2], float)
    for i in range(z_k.shape[0]):
        rows.add(z_k[i] - z_prev[i] - float(shift[i]), 0.0, 0.0)


def drop_above(
    T_obj: ca.SX, rect_T: FloatArray, half: tuple[float, float], size: tuple[float, float, float],
    z_low: float, z_high: float, rows: Rows,
) -> None:
    """The held object's centre over the rectangle (T (4, 4), half extents [m]), upright, its bottom in
    [z_low, z_high] [m]."""
    inside_rectangle(T_obj[:2, 3], rect_T, half, rows)
    rows.add(T_obj[2, 3] - size[2] / 2, z_low, z_high)
    rows.add(T_obj[2, 2], 0.999, ca.inf)  # upright
