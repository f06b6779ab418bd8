"""Constraint factors on one robot configuration, as CasADi expressions (the shared building blocks of
the keyframe NLP, the path NLP and the reachability graph's IK).

A factor returns rows ``(g, lower, upper)``. Shapes: the robot by spheres on the arm (frames along the
manipulator) and circles on the base footprint; the world by boxes. Distances are smooth signed
distances (``box_sdf``), so IPOPT sees gradients everywhere.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rlgp_exec.reach.ik import _smooth_pos, arm_spheres, base_circles, box_sdf, box_sdf_columns
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene.geometry import Box

__all__ = [
    "GRASP_DEPTH",
    "RobotSymbols",
    "Rows",
    "approach_bounds",
    "approach_rows",
    "box_clear",
    "closing_bounds",
    "footprint_clear",
    "grasp_point",
    "grasp_top",
    "inside_rectangle",
    "points_apart",
    "points_box_clear",
    "upright_match",
    "yaw_pose",
]


@dataclass
class Rows:
    """Constraint rows g with bounds lower <= g <= upper."""

    g: list[ca.SX]
    lower: list[float]
    upper: list[float]

    def add(self, g: ca.SX, lower: float, upper: float) -> None:
        self.g.append(g)
        self.lower.append(lower)
        self.upper.append(upper)

    def add_all(self, g: ca.SX, lower: Sequence[float] | FloatArray, upper: float) -> None:
        """One row per element of the vector ``g`` (column-major), each with its lower bound."""
        parts = ca.vertsplit(ca.vec(g))
        if len(parts) != len(lower):
            raise ValueError(f"Rows.add_all: {len(parts)} rows, {len(lower)} lower bounds")
        self.g += parts
        self.lower += [float(v) for v in lower]
        self.upper += [upper] * len(parts)

    @classmethod
    def empty(cls) -> Rows:
        return cls([], [], [])


class RobotSymbols:
    """The robot at one symbolic configuration z = [x, y, yaw, q_arm, q_extra] (``extra``: indices of
    further joints that move, e.g. a torso lift outside the arm; the other joints fixed). ``frames``:
    further frames whose transforms (``frame``) come from the same forward kinematics as the tool's and
    the arm spheres' (one expression: rows on any of them share it)."""

    def __init__(
        self, model: RobotModel, q_nominal: FloatArray, manipulator: str | None, z: ca.SX, extra: tuple[int, ...] = (),
        frames: Sequence[str] = (),
    ) -> None:
        self.model, self.manip = model, model.manipulator(manipulator)
        self.idx = np.array([*model.group("base"), *model.group(self.manip.group), *extra], dtype=int)
        q = ca.SX(ca.DM(np.asarray(q_nominal, float)))
        for k, i in enumerate(self.idx):
            q[int(i)] = z[k]
        self.z, self.q = z, q
        self.spheres = arm_spheres(model, self.manip.name)
        names = tuple(dict.fromkeys((self.manip.tool_frame, *(f for f, _ in self.spheres), *frames)))
        Ts = model.casadi_fk(names)(q)
        self._T = dict(zip(names, Ts if isinstance(Ts, (list, tuple)) else [Ts], strict=True))
        self.T_tool = self._T[self.manip.tool_frame]
        self.sphere_T = [self._T[f] for f, _ in self.spheres]
        self.circles = base_circles(model)

    def frame(self, name: str) -> ca.SX:
        """T_world_frame (4, 4) of the tool, an arm sphere's frame or one of ``frames``."""
        T = self._T.get(name)
        if T is None:
            raise KeyError(f"RobotSymbols: frame {name!r} not built; built: {sorted(self._T)}")
        return T

    @property
    def tool_pos(self) -> ca.SX:
        return self.T_tool[:3, 3]

    def tool_axis(self, axis: tuple[float, float, float]) -> ca.SX:
        return self.T_tool[:3, :3] @ ca.DM(axis)


def box_clear(
    rs: RobotSymbols, boxes: list[Box], rows: Rows, margin: float = 0.0, tool_margin: float | None = None,
    skip: tuple[str, ...] = (),
) -> None:
    """Every arm sphere at least its radius (+ margin; the tool frame's sphere + ``tool_margin`` if given)
    from every box (per box, all spheres at once: one matrix product and one mapped ``box_sdf``, not a
    few CasADi calls per sphere). The spheres on the frames in ``skip`` have no rows (a pick's tool and
    palm, where the fingers' and the hand's own spheres keep them off the neighbours)."""
    keep = [i for i, (f, _) in enumerate(rs.spheres) if f not in skip]
    if not boxes or not keep:
        return
    centres = ca.horzcat(*(rs.sphere_T[i][:3, 3] for i in keep))  # (3, S) world
    tool_frame = rs.manip.tool_frame
    lower = [r + (tool_margin if tool_margin is not None and f == tool_frame else margin)
             for f, r in (rs.spheres[i] for i in keep)]
    for b in boxes:
        Tinv = np.linalg.inv(b.T)
        rows.add_all(box_sdf_columns(ca.DM(Tinv[:3, :3]) @ centres, Tinv[:3, 3], np.asarray(b.size) / 2), lower,
                     ca.inf)


def footprint_clear(
    rs: RobotSymbols, rects: list[tuple[FloatArray, FloatArray]], rows: Rows, margin: float = 0.03
) -> None:
    """The base circles clear of fixture footprints: rects are (T (4, 4), size (3,)) of fixtures."""
    if not rects or not rs.circles:
        return
    z = rs.z
    c, s = ca.cos(z[2]), ca.sin(z[2])
    circles = np.asarray(rs.circles, float)  # (C, 3): centre x y in the base frame, radius
    cx, cy = ca.DM(circles[:, 0]), ca.DM(circles[:, 1])
    wx, wy = z[0] + c * cx - s * cy, z[1] + s * cx + c * cy  # (C,) world, all circles at once
    lower = [float(r) + margin for r in circles[:, 2]]
    for T, size in rects:
        R2 = T[:2, :2]
        lx = R2[0, 0] * (wx - T[0, 3]) + R2[1, 0] * (wy - T[1, 3])
        ly = R2[0, 1] * (wx - T[0, 3]) + R2[1, 1] * (wy - T[1, 3])
        dx = _smooth_pos(ca.sqrt(lx * lx + 1e-9) - size[0] / 2)
        dy = _smooth_pos(ca.sqrt(ly * ly + 1e-9) - size[1] / 2)
        rows.add_all(ca.sqrt(dx * dx + dy * dy + 1e-9), lower, ca.inf)


GRASP_DEPTH = 0.025  # [m] a top grasp's tool point below the object's top (at most half its height)


def grasp_point(T_obj: FloatArray, size: tuple[float, float, float], depth: float = GRASP_DEPTH) -> FloatArray:
    """A top grasp's tool point (world (3,) [m]): ``depth`` below the top centre of an object at T_obj
    (4, 4) of full extents ``size``, at most half its height."""
    return T_obj[:3, 3] + np.array([0.0, 0.0, size[2] / 2 - min(depth, size[2] / 2)])


def grasp_top(
    rs: RobotSymbols,
    T_obj: FloatArray | ca.SX | ca.DM,
    size: tuple[float, float, float],
    rows: Rows,
    depth: float = GRASP_DEPTH,
    max_tilt: float = 0.6,
) -> ca.SX:
    """A grasp from above: the tool point ``depth`` below the object's top centre, the approach axis
    pointing down within ``max_tilt`` [rad] of vertical (a tilted hand reaches further across a
    table), the fingers closing horizontally across two opposite faces (along the object's x or y).
    Returns the tilt measure 1 + a_z (0 when vertical), for the objective to prefer upright hands."""
    if isinstance(T_obj, ca.SX):  # an object where an earlier keyframe set it down (upright): an expression
        top_sx = T_obj[:3, 3] + ca.DM([0.0, 0.0, size[2] / 2 - min(depth, size[2] / 2)])
        for i in range(3):
            rows.add(rs.tool_pos[i] - top_sx[i], 0.0, 0.0)
    else:
        top = grasp_point(np.asarray(T_obj, float), size, depth)
        for i in range(3):
            rows.add(rs.tool_pos[i] - float(top[i]), 0.0, 0.0)
    a = rs.tool_axis(rs.manip.approach)
    for g, lower, upper in approach_rows(a, max_tilt):
        rows.add(g, lower, upper)
    c = rs.tool_axis(rs.manip.closing)
    rows.add(c[2], *closing_bounds(max_tilt))
    ox, oy = T_obj[:3, 0], T_obj[:3, 1]
    if not isinstance(T_obj, ca.SX):
        ox, oy = ca.DM(np.asarray(ox, float)), ca.DM(np.asarray(oy, float))
    rows.add(ca.dot(c, ox) * ca.dot(c, oy), 0.0, 0.0)
    return 1.0 + a[2]


def approach_rows(a: ca.SX, max_tilt: float) -> list[tuple[ca.SX, float, float]]:
    """Rows (g, lower, upper) for a unit approach axis ``a`` (3,) pointing down within ``max_tilt`` [rad] of
    vertical: a_z <= -cos(max_tilt), and a_x, a_y in [-1, 1] (always true); when ``max_tilt`` is 0, a_x = a_y = 0
    and a_z <= 0 instead. a_z = -1 as a row is degenerate: it is a_z's minimum, where its gradient vanishes,
    and IPOPT's steps then fail (``Error_In_Step_Computation``) or crawl. No row has a bound a unit
    vector's component reaches only at its extreme (-1 or 1): those bounds hold anyway, and are as degenerate."""
    return [(g, lo, hi) for g, (lo, hi) in zip((a[2], a[0], a[1]), approach_bounds(max_tilt), strict=True)]


def approach_bounds(max_tilt: float) -> list[tuple[float, float]]:
    """The (lower, upper) bounds of ``approach_rows``' rows (a_z, a_x, a_y) for ``max_tilt`` [rad]."""
    lim = 0.0 if max_tilt <= 0.0 else 1.0
    return [(-ca.inf, -float(np.cos(max_tilt)) if max_tilt > 0.0 else 0.0), (-lim, lim), (-lim, lim)]


def closing_bounds(max_tilt: float) -> tuple[float, float]:
    """Bounds of a top grasp's closing-axis row c_z (the fingers close horizontally): c_z = 0, except for a
    vertical grasp (``max_tilt`` 0), where a_x = a_y = 0 already makes it hold (c is square to a); as a row it
    would then be linearly dependent on those two, and IPOPT regularises every iteration's KKT system
    (pick_place_pr2 seed 1: ~3x the time per iteration)."""
    return (-ca.inf, ca.inf) if max_tilt <= 0.0 else (0.0, 0.0)


def inside_rectangle(p_xy: ca.SX, T: FloatArray | ca.SX, half: tuple[float, float], rows: Rows) -> None:
    """A world point's x, y inside a rectangle of half extents ``half`` centred on T's origin (its axes);
    T (4, 4) a number or an expression (a support placed at an earlier keyframe)."""
    R2 = T[:2, :2]
    lx = R2[0, 0] * (p_xy[0] - T[0, 3]) + R2[1, 0] * (p_xy[1] - T[1, 3])
    ly = R2[0, 1] * (p_xy[0] - T[0, 3]) + R2[1, 1] * (p_xy[1] - T[1, 3])
    rows.add(lx, -half[0], half[0])
    rows.add(ly, -half[1], half[1])


def grasp_top_round(
    rs: RobotSymbols, T_obj: FloatArray | ca.SX | ca.DM, size: tuple[float, float, float], rows: Rows, **kw
) -> ca.SX:
    """``grasp_top`` for a cylinder (axis up): the fingers may close across it from any side, so the
    hand's roll is free (the optimiser can turn the open fingers away from a wall). Returns 1 + a_z."""
    mine = Rows.empty()
    tilt = grasp_top(rs, T_obj, size, mine, **kw)  # depth, max_tilt
    # grasp_top's rows: tool position (3), approach (3), closing horizontal, then the faces' row: dropped
    for g, lo, hi in list(zip(mine.g, mine.lower, mine.upper, strict=True))[:7]:
        rows.add(g, lo, hi)
    return tilt


__all__ += ["grasp_top_round"]

# ---------------------------------------------------------------------------------------------------
# Factors on upright object poses w = [x, y, z, yaw] (world frame [m, rad]) and on point sets, shared by
# the GNPP graph-NLP (appended; the factors above keep their signatures).


def yaw_pose(w: ca.SX) -> ca.SX:
    """The (4, 4) transform of an upright pose w = [x, y, z, yaw]."""
    c, s = ca.cos(w[3]), ca.sin(w[3])
    T = ca.SX.eye(4)
    T[0, 0], T[0, 1], T[1, 0], T[1, 1] = c, -s, s, c
    T[0, 3], T[1, 3], T[2, 3] = w[0], w[1], w[2]
    return T


def points_box_clear(
    points: list[ca.SX], radii: list[float], w_box: ca.SX, half: FloatArray, rows: Rows, margin: float = 0.0
) -> None:
    """Every sphere (centre ``points[k]`` (3,) world, radius ``radii[k]``) at least its radius (+ margin)
    from an upright box of half extents ``half`` at pose ``w_box`` = [x, y, z, yaw] (symbolic)."""
    c, s = ca.cos(w_box[3]), ca.sin(w_box[3])
    for p, r in zip(points, radii, strict=True):
        dx, dy, dz = p[0] - w_box[0], p[1] - w_box[1], p[2] - w_box[2]
        local = ca.vertcat(c * dx + s * dy, -s * dx + c * dy, dz)
        rows.add(box_sdf(local, np.asarray(half, float)), r + margin, ca.inf)


def points_apart(
    a: list[ca.SX], ra: list[float], b: list[ca.SX], rb: list[float], rows: Rows, margin: float = 0.0
) -> None:
    """Spheres of set a clear of spheres of set b (squared centre distances, smooth)."""
    for p, r1 in zip(a, ra, strict=True):
        for q, r2 in zip(b, rb, strict=True):
            rows.add(ca.sumsqr(p - q), (r1 + r2 + margin) ** 2, ca.inf)


def upright_match(T: ca.SX, w: ca.SX, rows: Rows) -> None:
    """A transform T (4, 4) equals the upright pose w = [x, y, z, yaw]: 3 position rows, 2 rows for the
    z axis vertical, 1 row for the yaw modulo pi (6 independent equalities: one per degree of freedom,
    so the Jacobian keeps full rank; a box turned by pi is the same box)."""
    for i in range(3):
        rows.add(T[i, 3] - w[i], 0.0, 0.0)
    rows.add(T[0, 2], 0.0, 0.0)
    rows.add(T[1, 2], 0.0, 0.0)
    c, s = ca.cos(w[3]), ca.sin(w[3])
    rows.add(T[1, 0] * c - T[0, 0] * s, 0.0, 0.0)
