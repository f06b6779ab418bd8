"""Initial values of the drawer actions' variables in a plan's graph-NLP (``guess.initial_guess``): the arm
at a knob (``KnobIK``: the ``Knob`` and ``ColFix`` factors' rows, nearest a reference posture), the arm
after a drive (the base moved along the drawer's axis, as ``Drive`` has it), and where a dropped object
lands (the drop rectangle, apart from what is in the drawer already) with the hand that releases it over
there.
"""

from __future__ import annotations

import math
from typing import Any

import casadi as ca
import numpy as np

from rlgp_exec.ipopt import LEAN
from rlgp_exec.planning.gnpp.drawer_pntc import opening_atom
from rlgp_exec.planning.gnpp.spots import free_spot
from rlgp_exec.planning.margins import FEAS_TOL
from rlgp_exec.planning.nlp.keyframes import DROP_HIGH, DROP_LOW
from rlgp_exec.planning.symbolic.model import SymbolicState
from rlgp_exec.robot.model import FloatArray

__all__ = ["KnobIK", "drive_shift", "drop_guess"]

KNOB_RANGES = (0.45, 0.6, 0.75)  # [m] a mobile base's starts this far out from a knob, facing it
IK_MAX_ITER = 100


class KnobIK:
    """q (the arm's variable) with the hand on a cabinet's knob, clear of the fixtures and drawers, nearest
    a reference posture; cached per (arm, cabinet, opening state)."""

    def __init__(self, lib) -> None:
        self.lib = lib
        self._memo: dict[tuple[str, str, str], tuple[bool, FloatArray]] = {}

    def solve(self, arm: str, cabinet: str, s: SymbolicState, q_ref: FloatArray) -> tuple[bool, FloatArray]:
        state = opening_atom(s, cabinet)[0]
        key = (arm, cabinet, state)
        if key not in self._memo:
            self._memo[key] = self._solve(arm, cabinet, state, np.asarray(q_ref, float))
        return self._memo[key]

    def _solve(self, arm: str, cabinet: str, state: str, q_ref: FloatArray) -> tuple[bool, FloatArray]:
        lib = self.lib
        n = len(lib.arm_index(arm))
        knob = lib.factor(("Knob", arm, cabinet, state))
        col = lib.factor(("ColFix", arm, f"{cabinet}:{state}+knob"))
        q = ca.SX.sym("q", n)
        g = ca.vertcat(knob.fn(q), col.fn(q))
        lbg, ubg = np.r_[knob.lower, col.lower], np.r_[knob.upper, col.upper]
        home = lib.home_q(arm)
        opts: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                "ipopt.max_iter": IK_MAX_ITER}
        solver = ca.nlpsol(f"knob_ik_{arm}", "ipopt", {"x": q, "f": ca.sumsqr(q - ca.DM(home)), "g": g}, opts | LEAN)
        lo, hi = lib.var_bounds("q", arm)
        starts = [q_ref, home]
        if lib.mobile:  # the base in front of the knob, facing the cabinet
            v = lib.drawers[cabinet]
            p = v.T_world_knob(lib.opening(cabinet, state))[:3, 3]
            ax = v.axis_world
            for r in KNOB_RANGES:
                z = home.copy()
                z[:2] = p[:2] + r * ax[:2]
                z[2] = math.atan2(-ax[1], -ax[0])
                starts.insert(0, z)
        for x0 in starts:
            res = solver(x0=np.clip(x0, lo, hi), lbx=lo, ubx=hi, lbg=lbg, ubg=ubg)
            qs = np.asarray(res["x"]).reshape(-1)
            gs = np.asarray(res["g"]).reshape(-1)
            if np.all(gs >= lbg - FEAS_TOL) and np.all(gs <= ubg + FEAS_TOL):
                return True, qs
        return False, np.asarray(q_ref, float)


def drive_shift(lib, cabinet: str, opens: bool) -> FloatArray:
    """(2,) [m] the base's move in an open (``opens``) or close of the cabinet's drawer (``Drive``)."""
    v = lib.drawers[cabinet]
    return (v.travel if opens else -v.travel) * np.asarray(v.axis_world[:2], float)


def drop_guess(lib, obj: str, cabinet: str, others: list[FloatArray]) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(the object's world pose at the release (4,), where it lands in the drawer's frame (4,), the tool
    point (3,) [m] that holds it there): over the drop rectangle, its bottom midway between the drop's
    height bounds, as far from the drawer-frame poses ``others`` as the rectangle allows."""

    o, v = lib.objects[obj], lib.drawers[cabinet]
    d = v.travel
    rect, half = v.drop_rect(d, max(o.size[0], o.size[1]) / 2)
    T_d = v.T_world_drawer(d)
    # the rectangle's own extents (drop_rect has shrunk it by the object already): a footprint of 0 for free_spot
    world_others = [lib.in_world(cabinet, d, w)[:2] for w in others]
    xy = free_spot(rect, np.asarray(half, float), (0.0, 0.0, 0.0), world_others)
    yaw = math.atan2(T_d[1, 0], T_d[0, 0])
    h = o.size[2]
    bottom = v.rim_z(d) + 0.5 * (DROP_LOW + DROP_HIGH)
    release = np.array([xy[0], xy[1], bottom + h / 2, yaw])
    land_world = np.eye(4)
    land_world[:3, :3] = T_d[:3, :3]
    land_world[:3, 3] = [xy[0], xy[1], v.floor_z(d) + h / 2]
    land = lib.in_drawer_frame(cabinet, d, land_world)
    top = release[:3] + np.array([0.0, 0.0, h / 2 - min(0.025, h / 2)])
    return release, land, top
