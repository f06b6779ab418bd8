"""The drawer factors' functions for GNPP's graph-NLP (``drawer_pntc`` names them), built from the shared
drawer rows of R-LGP's keyframe NLP (``nlp.drawer_factors``: the knob grasp, the articulated drive, the
drop over the open drawer) and the shared drawer geometry (``planning.drawers``).

``DrawerFactors`` is mixed into ``geometry.FactorLib``: ``factor(("Knob", ...))`` finds ``_f_Knob`` there.
An object in a drawer has its pose w = [x, y, z, yaw] in the drawer's frame (``T_world_drawer`` at the
opening the logic state gives: 0 closed, ``travel`` open); ``in_world`` turns it into a world pose.
"""

from __future__ import annotations

import math
from functools import cached_property

import casadi as ca
import numpy as np

from rlgp_exec.planning.drawers import DrawerView, drawer_views
from rlgp_exec.planning.gnpp.drawer_guess import KnobIK
from rlgp_exec.planning.gnpp.held_pose import rel_pose
from rlgp_exec.planning.nlp.drawer_factors import drop_above, follow_prismatic, knob_grasp
from rlgp_exec.planning.nlp.factors import Rows, inside_rectangle
from rlgp_exec.planning.nlp.keyframes import DROP_HIGH, DROP_LOW
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene.geometry import PANEL, Box

__all__ = ["DROP_MARGIN", "DrawerFactors", "parse_tag"]

DROP_MARGIN = 0.01  # [m] two objects in one drawer keep this much apart (beyond their Minkowski bound)


def parse_tag(tag: str) -> dict[str, tuple[str, bool]]:
    """A ``ColFix`` drawer tag ("c:open+knob,d:closed") -> cabinet -> (opening state, hand on its knob)."""
    out = {}
    for part in filter(None, tag.split(",")):
        c, state = part.split(":")
        out[c] = (state.removesuffix("+knob"), state.endswith("+knob"))
    return out


def _yaw_of(T) -> float:
    return math.atan2(float(T[1, 0]), float(T[0, 0]))


class DrawerFactors:
    """The drawer factor builders (``_f_Knob``, ``_f_Drive``, ``_f_Drop``, ``_f_InDrawer``) and the drawer
    geometry ``FactorLib``'s collision factors read. Needs ``scene``, ``objects``, ``arm_shapes``,
    ``_symbols``, ``upright`` of the class it is mixed into."""

    @cached_property
    def drawers(self) -> dict[str, DrawerView]:
        return drawer_views(self.scene)  # type: ignore[attr-defined]

    @cached_property
    def knob_ik(self):
        """The arm's IK onto a knob (``drawer_guess.KnobIK``), one cache per library (planning call)."""
        return KnobIK(self)

    def opening(self, cabinet: str, state: str) -> float:
        """[m] the drawer's opening in a logic state ("open": its travel, "closed": 0)."""
        return self.drawers[cabinet].travel if state == "open" else 0.0

    # ----------------------------------------------------------------- frames
    def in_world(self, cabinet: str, opening: float, w: FloatArray) -> FloatArray:
        """The world pose (4,) [x, y, z, yaw] of a pose w (4,) in the cabinet's drawer frame at ``opening``."""
        T = self.drawers[cabinet].T_world_drawer(opening)
        p = T[:3, :3] @ np.asarray(w[:3], float) + T[:3, 3]
        return np.array([p[0], p[1], p[2], float(w[3]) + _yaw_of(T)])

    def in_drawer_frame(self, cabinet: str, opening: float, T_world_obj: FloatArray) -> FloatArray:
        """The pose (4,) in the drawer frame of an upright object at T_world_obj (4, 4)."""
        T = np.linalg.solve(self.drawers[cabinet].T_world_drawer(opening), T_world_obj)
        return np.array([T[0, 3], T[1, 3], T[2, 3], _yaw_of(T)])

    def _in_world_sx(self, cabinet: str, opening: float, w: ca.SX) -> ca.SX:
        T = self.drawers[cabinet].T_world_drawer(opening)
        p = ca.DM(T[:3, :3]) @ w[:3] + ca.DM(T[:3, 3])
        return ca.vertcat(p, w[3] + _yaw_of(T))

    # ----------------------------------------------------------------- obstacles
    def drawer_obstacles(self, tag: str) -> tuple[list[Box], list[tuple[FloatArray, FloatArray]]]:
        """(the drawers' boxes the arm keeps clear of, the open drawers' footprints (T (4, 4), size (3,))
        the base keeps clear of) for a ``ColFix`` tag: every drawer at its opening, but the boxes of the
        one whose knob the hand is on (its fingers are round the knob)."""
        boxes: list[Box] = []
        rects: list[tuple[FloatArray, FloatArray]] = []
        for c, (state, knob) in parse_tag(tag).items():
            v, d = self.drawers[c], self.opening(c, state)
            if not knob:
                boxes += v.boxes(d)
            if d > 0.0:
                rects.append((v.T_world_drawer(d), np.asarray(v.geometry.inner_box.size) + 2 * PANEL))
        return boxes, rects

    # ----------------------------------------------------------------- factors
    def _f_Knob(self, arm: str, cabinet: str, state: str):
        """The hand on the knob (``nlp.drawer_factors.knob_grasp``) of the drawer at its opening in ``state``."""
        q, rows = ca.SX.sym("q", len(self.arm_index(arm))), Rows.empty()  # type: ignore[attr-defined]
        rs = self._symbols(arm, q)  # type: ignore[attr-defined]
        knob_grasp(rs, self.drawers[cabinet].T_world_knob(self.opening(cabinet, state)), rows)
        return [q], rows

    def _f_Drive(self, arm: str, cabinet: str, what: str):
        """The articulated drive (``follow_prismatic``): q_b is q_a with the base moved along the drawer's
        axis by its travel (out to open, in to close), the arm held still, as R-LGP's keyframes drive it."""
        n = len(self.arm_index(arm))  # type: ignore[attr-defined]
        qa, qb, rows = ca.SX.sym("qa", n), ca.SX.sym("qb", n), Rows.empty()
        v = self.drawers[cabinet]
        follow_prismatic(qb, qa, v.axis_world, v.travel if what == "open" else -v.travel, rows)
        return [qa, qb], rows

    def _f_Drop(self, obj: str, arm: str, cabinet: str):
        """The held object (held pose r, in the hand at q) upright over the open drawer's reachable part, its
        bottom a little below or above the rim (``drop_above``, R-LGP's bounds); w, its pose in the drawer
        frame after the fall, is straight below the release, turned as it was."""
        n = len(self.arm_index(arm))  # type: ignore[attr-defined]
        q, w, r, rows = ca.SX.sym("q", n), ca.SX.sym("w", 4), ca.SX.sym("r", 4), Rows.empty()
        o, v = self.objects[obj], self.drawers[cabinet]  # type: ignore[attr-defined]
        d = v.travel
        T = self.arm_shapes(arm).fn(q)[1] @ rel_pose(r, self.upright(arm))  # type: ignore[attr-defined]
        rect, half = v.drop_rect(d, max(o.size[0], o.size[1]) / 2)
        rim = v.rim_z(d)
        drop_above(T, rect, half, o.size, rim + DROP_LOW, rim + DROP_HIGH, rows)
        land = self._in_world_sx(cabinet, d, w)
        rows.add(T[0, 3] - land[0], 0.0, 0.0)
        rows.add(T[1, 3] - land[1], 0.0, 0.0)
        c, s = ca.cos(land[3]), ca.sin(land[3])
        rows.add(T[1, 0] * c - T[0, 0] * s, 0.0, 0.0)  # the same yaw, modulo pi (``upright_match``)
        return [q, w, r], rows

    def _f_InDrawer(self, obj: str, cabinet: str):
        """w (drawer frame) on the drawer's floor, inside the part of the interior a drop can reach."""
        w, rows = ca.SX.sym("w", 4), Rows.empty()
        o, v = self.objects[obj], self.drawers[cabinet]  # type: ignore[attr-defined]
        d = v.travel
        T_d = v.T_world_drawer(d)
        rect, half = v.drop_rect(d, max(o.size[0], o.size[1]) / 2)
        inside_rectangle(w[:2], np.asarray(np.linalg.solve(T_d, rect), float), half, rows)
        inner = v.geometry.inner_box
        floor = float(inner.T[2, 3] - inner.size[2] / 2)  # the drawer frame's height of its floor
        rows.add(w[2] - (floor + o.size[2] / 2), 0.0, 0.0)
        return [w], rows
