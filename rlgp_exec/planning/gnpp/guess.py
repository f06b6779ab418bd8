"""Initial values for a plan's graph-NLP: object poses followed through the logic states, arm
configurations from a small top-grasp IK (cached), so that every NLP of the plan starts from the same,
reasonable point."""

from __future__ import annotations

import logging
import math
from collections.abc import Mapping, Sequence
from typing import Any

import casadi as ca
import numpy as np

from rlgp_exec.ipopt import LEAN
from rlgp_exec.planning.capabilities import reach_segments
from rlgp_exec.planning.gnpp import drawer_guess, drawer_pntc
from rlgp_exec.planning.gnpp.geometry import MAX_TILT, FactorLib
from rlgp_exec.planning.gnpp.lm import TOL as LM_TOL
from rlgp_exec.planning.gnpp.lm import LevenbergMarquardt
from rlgp_exec.planning.gnpp.pntc import Factor, Var, moving, parents
from rlgp_exec.planning.gnpp.spots import free_spot as _free_spot
from rlgp_exec.planning.margins import FEAS_TOL, PLACE_LIFT, TOOL_POS_TOL
from rlgp_exec.planning.symbolic.model import SymbolicState
from rlgp_exec.robot.model import FloatArray

__all__ = ["TopIK", "ik_seed", "initial_guess", "rel_T"]

log = logging.getLogger(__name__)
RESTARTS = 3  # seeded perturbations of the start posture tried after the reference and the start
RING = 0.6  # [m] a mobile arm's IK also starts with its base this far from the target (see _ring_starts)
#: IPOPT's iteration limit per IK start: the solves that reach the point converge well within it, while
#: those that do not would run to IPOPT's default 100 and dominate the IK's CPU
IK_MAX_ITER = 60
#: a fixed-base arm's IK adds IPOPT's heuristics for likely infeasible problems: a point out of reach
#: (a pick across the body) ends sooner than at ``IK_MAX_ITER``, each of the five starts, with the same
#: answers on recorded calls. Not for a mobile base: there the HSR's answers changed
IK_FIXED_BASE = {"ipopt.expect_infeasible_problem": "yes"}
#: a fixed-base arm's IK tries IPOPT from its starts after the first (the start posture, random ones) only
#: where Levenberg-Marquardt (``lm``, a few ms) reaches the point from that start: a point out of reach
#: failed IPOPT from every start, 80-90 % of the IK's CPU (tower_pr2 seed 0: 4 such calls, 0.3 s)
IK_SCREEN = True


class TopIK:
    """q (the arm's variable, ``FactorLib.arm_index``) for one arm with the tool at a point, approach
    straight down, fingers horizontal, the arm clear of the fixtures (``ColFix``; a mobile base's
    footprint too); closest to a reference posture. Also used to lift a hand (the base held)."""

    def __init__(self, lib: FactorLib) -> None:
        self.lib = lib
        self._solvers: dict[str | tuple[str, ...], tuple] = {}  # by arm (and ColFix key, ``_solver``)
        self._memo: dict[tuple, tuple[bool, FloatArray]] = {}
        #: points a fixed-base arm reached from none of the starts: asked again with another reference
        #: posture, only that posture is tried (the other starts are the same whatever the reference);
        #: on Hanoi such failures (the keyframes of the learnt reach conflicts, asked again in every
        #: later plan's guess) took 2.2 s of CPU, 12 % of the run
        self._unreachable: set[tuple] = set()
        self.n_solves = 0
        self.n_screened = 0  # later starts first tried by LM (``IK_SCREEN``)
        self.n_beyond = 0  # calls answered by the reach bound alone (``_beyond``)
        self.carry: dict[str, FloatArray | None] = {}  # per arm: ``motion.carry_q``'s posture, solved once

    def _solver(self, arm: str, col_key: tuple[str, ...] | None = None):
        """The IK's solver for ``arm`` with the ``ColFix`` factor ``col_key`` (default: the fixtures alone;
        a drawer tag: the drawers at their openings too, ``drawer_pntc.colfix``)."""
        key: str | tuple[str, ...] = arm if col_key is None else (arm, *col_key)
        if key not in self._solvers:
            man = self.lib.model.manipulator(arm)
            n = len(self.lib.arm_index(arm))
            q, p = ca.SX.sym("q", n), ca.SX.sym("p", 3 + n)
            T = self.lib.arm_shapes(arm).fn(q)[1]
            a = T[:3, :3] @ ca.DM(man.approach)
            c = T[:3, :3] @ ca.DM(man.closing)
            col = self.lib.factor(col_key or ("ColFix", arm))
            g = ca.vertcat(T[:3, 3] - p[:3], a[2], c[2], col.fn(q))
            lbg = np.r_[np.zeros(3), -1.0, 0.0, col.lower]
            ubg = np.r_[np.zeros(3), -np.cos(MAX_TILT), 0.0, col.upper]
            opts: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                    "ipopt.max_iter": IK_MAX_ITER}
            if not self.lib.mobile:
                opts |= IK_FIXED_BASE
            s = ca.nlpsol(f"top_ik_{arm}", "ipopt", {"x": q, "p": p, "f": ca.sumsqr(q - p[3:]), "g": g}, opts | LEAN)
            screen = None if self.lib.mobile else LevenbergMarquardt(q, p, g, IK_MAX_ITER)
            self._solvers[key] = (s, lbg, ubg, screen)
        return self._solvers[key]

    def solve(
        self, arm: str, pos: FloatArray, q_ref: FloatArray, fixed_base: bool = False,
        col_key: tuple[str, ...] | None = None,
    ) -> tuple[bool, FloatArray]:
        """(ok, q): from q_ref, else from the start posture and a few seeded perturbations of it (a
        mobile arm's base: q_ref's). ``fixed_base``: a mobile arm's base stays at q_ref's. ``col_key``:
        the ``ColFix`` factor to keep (``_solver``)."""
        fixed_base = fixed_base and self.lib.mobile
        key = (arm, *np.round(pos, 3), *np.round(q_ref, 2), *((True,) if fixed_base else ()), *(col_key or ()))
        if key in self._memo:
            return self._memo[key]
        if (fixed_base or not self.lib.mobile) and self._beyond(arm, pos, q_ref):
            self.n_beyond += 1
            self._memo[key] = (False, np.asarray(q_ref, float))
            return self._memo[key]
        s, lbg, ubg, screen = self._solver(arm, col_key)
        lo, hi = self.lib.var_bounds("q", arm)
        rng = np.random.default_rng(7)
        home = self.lib.home_q(arm)
        if self.lib.mobile:
            home[:3] = q_ref[:3]
            if fixed_base:
                lo, hi = lo.copy(), hi.copy()
                lo[:3] = hi[:3] = q_ref[:3]
        point = (arm, *np.round(pos, 3), *(col_key or ()))
        starts = [q_ref, home]
        if self.lib.mobile and not fixed_base:  # the base on a ring round the point, facing it
            starts += _ring_starts(home, pos, q_ref)
        starts += [home + rng.normal(0.0, 0.6, home.size) for _ in range(RESTARTS)]
        if point in self._unreachable:
            starts = starts[:1]
        out = (False, np.asarray(q_ref, float))
        prm = np.r_[pos, q_ref]
        for k, q0 in enumerate(starts):
            x0 = np.clip(q0, lo, hi)
            if k > 0 and screen is not None and IK_SCREEN:  # a later start: IPOPT only if LM gets there from it
                self.n_screened += 1
                x_lm = screen(x0=x0, p=prm, lbx=lo, ubx=hi, lbg=lbg, ubg=ubg)["x"]
                if screen.violation(x_lm, prm, lbg, ubg) > LM_TOL:
                    continue
            res = s(x0=x0, p=prm, lbx=lo, ubx=hi, lbg=lbg, ubg=ubg)
            self.n_solves += 1
            q = np.asarray(res["x"]).reshape(-1)
            g = np.asarray(res["g"]).reshape(-1)
            err = np.linalg.norm(self.lib.tool_T(arm, q)[:3, 3] - pos)
            if err < TOOL_POS_TOL and np.all(g >= lbg - FEAS_TOL) and np.all(g <= ubg + FEAS_TOL):
                out = (True, q)
                break
        if not out[0] and not self.lib.mobile:
            self._unreachable.add(point)
        self._memo[key] = out
        return out

    def _beyond(self, arm: str, pos: FloatArray, q_ref: FloatArray) -> bool:
        """The point ``pos`` (3,) lies past ``arm_reach``'s bound from q_ref's base (and torso): no posture
        gets the tool there, so no start is tried (a fixed base's IK towards a far tray ran every start to
        its iteration limit)."""
        (seg,) = reach_segments(self.lib.model, self.lib.full_q({arm: np.asarray(q_ref, float)}), arm)
        return seg.gap_m(np.asarray(pos, float)) > 0.0


def _ring_starts(home: FloatArray, pos: FloatArray, q_ref: FloatArray) -> list[FloatArray]:
    """Starts (the arm's variable) for a mobile arm's IK towards ``pos``: the arm at ``home``'s posture,
    the base ``RING`` m from pos at eight bearings, facing it, nearest to q_ref's base first (from a base
    2 m away, facing elsewhere, the solver often stops at a fixture's footprint or out of reach)."""
    out = []
    for ang in np.linspace(-math.pi, math.pi, 8, endpoint=False):
        q = home.copy()
        q[:2] = pos[:2] + RING * np.array([math.cos(ang), math.sin(ang)])
        q[2] = ang + math.pi
        out.append(q)
    return sorted(out, key=lambda q: float(np.linalg.norm(q[:2] - q_ref[:2])))


def _held_of(lib: FactorLib, arm: str, q: FloatArray, w: FloatArray) -> FloatArray:
    """The held pose r = [d, s, psi, theta] of an object at world pose w in the hand at q."""
    R = (np.linalg.inv(lib.tool_T(arm, q)) @ lib.object_T(w))[:3]
    z, up = R[:3, 2], lib.upright(arm)
    a = up[:, 2]  # the upright object's z axis (the tool's -approach)
    # the tilt about the fingers' (tool y) axis that turns a onto z (in the tool's x-z plane)
    theta = math.atan2(a[2] * z[0] - a[0] * z[2], a[0] * z[0] + a[2] * z[2])
    ct, st = math.cos(theta), math.sin(theta)
    Ry = np.array([[ct, 0.0, st], [0.0, 1.0, 0.0], [-st, 0.0, ct]])
    M = up.T @ Ry.T @ R[:3, :3]
    psi = math.atan2(M[1, 0], M[0, 0])
    p = R[:3, 3]
    return np.array([-float(p @ z), float(p[1]), psi, theta])


def rel_T(r: FloatArray, upright: FloatArray) -> FloatArray:
    """T_tool_obj (4, 4) of the held pose r = [d, s, psi, theta] (``held_pose.rel_pose``, numerically)."""
    c, s = math.cos(r[2]), math.sin(r[2])
    Rz = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    ct, st = math.cos(r[3]), math.sin(r[3])
    Ry = np.array([[ct, 0.0, st], [0.0, 1.0, 0.0], [-st, 0.0, ct]])
    R = Ry @ upright @ Rz
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -r[0] * R[:, 2] + r[1] * np.array([0.0, 1.0, 0.0])
    return T


def _clear_spot(
    T_world_surface: FloatArray,
    half: FloatArray,
    size: Sequence[float],
    near: FloatArray,
    others: list[FloatArray],
    other_sizes: Sequence[Sequence[float]],
    gap: float = 0.04,
) -> FloatArray:
    """The xy (2,) on the surface nearest ``near`` whose footprint circle clears the other resting
    objects' by ``gap`` (fingers fit between): an object put down on a large surface (the table) where
    it was picked up would start on top of whatever rests there (objects taken off one stack one after
    another all start at one point, where a signed distance has no gradient). ``near`` if nothing does."""
    r = math.hypot(size[0], size[1]) / 2
    need = [r + math.hypot(s[0], s[1]) / 2 + gap for s in other_sizes]
    margin = max(size[0], size[1]) / 2
    ax, ay = (max(float(h) - margin, 0.0) for h in half[:2])
    grid = np.array([(x, y) for x in np.linspace(-ax, ax, 41) for y in np.linspace(-ay, ay, 25)])
    pts = T_world_surface[:2, 3] + grid @ T_world_surface[:2, :2].T
    ok = np.ones(len(pts), bool)
    for c, d in zip(others, need, strict=True):
        ok &= np.linalg.norm(pts - np.asarray(c)[None, :], axis=1) >= d
    if not others or not ok.any():
        return np.asarray(near, float).copy()
    dist = np.linalg.norm(pts - np.asarray(near)[None, :], axis=1)
    dist[~ok] = np.inf
    return pts[int(np.argmin(dist))].copy()


def initial_guess(
    lib: FactorLib, ik: TopIK, states: Sequence[SymbolicState], variables: Sequence[Var]
) -> dict[Var, FloatArray]:
    """A value for every variable of the plan's graph (and for arms' variables not in it); the drawer
    actions' from ``drawer_guess``."""
    arms = lib.arms
    world: dict[str, FloatArray] = {o: lib.start_pose(o) for o in lib.objects}
    q: dict[str, FloatArray] = {m: lib.home_q(m) for m in arms}
    out: dict[Var, FloatArray] = {}
    prev: dict[str, str] = parents(states[0])
    held: dict[str, FloatArray] = {}
    in_drawer: dict[str, FloatArray] = {}  # object -> its pose in its drawer's frame (4,)
    shifts: dict[int, FloatArray] = {}  # t -> the base's xy move by a drawer's drive into state t
    knob_ik = lib.knob_ik
    for t, s in enumerate(states):
        par = parents(s)
        drawers = bool(drawer_pntc.cabinets(s))

        def col(m: str, t: int = t, s: SymbolicState = s, drawers: bool = drawers) -> tuple[str, ...] | None:
            """The key of the ColFix factor of arm m at t (the drawers at their openings), None without drawers."""
            return drawer_pntc.colfix(t, s, states[t - 1] if t else None, m).key if drawers else None

        for m in arms:
            if t == 0:
                break
            c, c0 = drawer_pntc.knob_of(s, m), drawer_pntc.knob_of(states[t - 1], m)
            if c is not None and c0 is None:  # take_knob: the hand on the knob
                q[m] = knob_ik.solve(m, c, s, q[m])[1]
            elif drawer_pntc.drives(m, states[t - 1], s):  # the base moved with the drawer
                assert c0 is not None
                shifts[t] = drawer_guess.drive_shift(lib, c0, ("open", c0) in s)
                q[m] = q[m].copy()
                q[m][:2] += shifts[t]
        for o in sorted(par):
            p = par[o]
            if ("in", o, p) in s:  # in a drawer: dropped now, or where it is in the drawer's frame
                arm = prev.get(o)
                if arm in arms and o in held:
                    others = [w for b, w in in_drawer.items() if par.get(b) == p]
                    _, land, top = drawer_guess.drop_guess(lib, o, p, others)
                    ok, q[arm] = _keyframe_ik(lib, ik, arm, top, q[arm], col(arm))
                    if ok:  # the yaw it is held at (see the placement below)
                        T = lib.tool_T(arm, q[arm]) @ rel_T(held[o], lib.upright(arm))
                        land[3] = lib.in_drawer_frame(p, lib.drawers[p].travel, T)[3]
                    in_drawer[o] = land
                out[Var("x", o, t)] = in_drawer.get(o, world[o]).copy()
                continue
            if p in arms:
                if prev.get(o) != p:  # picked now: the arm goes to the object's top
                    h = lib.objects[o].size[2]
                    top = world[o][:3] + np.array([0.0, 0.0, h / 2 - min(0.025, h / 2)])
                    q[p] = _keyframe_ik(lib, ik, p, top, q[p], col(p))[1]
                    _share_base(lib, q, p)
                    held[o] = _held_of(lib, p, q[p], world[o])
                out[Var("x", o, t)] = held.get(o, lib.held_pose(o))
                continue
            if prev.get(o) != p:  # placed now
                h = lib.objects[o].size[2]
                if p in lib.objects:
                    wp = world[p]
                    world[o] = np.array([wp[0], wp[1], wp[2] + (h + lib.objects[p].size[2]) / 2 + PLACE_LIFT, wp[3]])
                else:
                    region = any(r.name == p for r in lib.scene.regions)
                    others = [world[b][:2] for b, pb in par.items() if b != o and pb not in arms]
                    T, half, z = lib.surface(p)
                    if region:
                        xy = _free_spot(T, np.asarray(half, float), lib.objects[o].size, others)
                    else:
                        sizes = [lib.objects[b].size for b, pb in par.items() if b != o and pb not in arms]
                        xy = _clear_spot(T, np.asarray(half, float), lib.objects[o].size, world[o][:2], others, sizes)
                    world[o] = np.array([xy[0], xy[1], z + h / 2 + PLACE_LIFT, world[o][3]])
                arm = prev.get(o)
                if arm in arms:
                    top = world[o][:3] + np.array([0.0, 0.0, h / 2 - min(0.025, h / 2)])
                    ok, q[arm] = _keyframe_ik(lib, ik, arm, top, q[arm], col(arm))
                    _share_base(lib, q, arm)
                    if ok and o in held:
                        # the object put down turned as the hand holds it: the Kin factor's yaw row
                        # (sine of the yaw difference) is stationary a quarter turn off, where a
                        # start with the pose's old yaw could leave it (a false conflict)
                        T = lib.tool_T(arm, q[arm]) @ rel_T(held[o], lib.upright(arm))
                        world[o][3] = math.atan2(T[1, 0], T[0, 0])
            out[Var("x", o, t)] = world[o].copy()
        for m in arms:
            out[Var("q", m, t)] = q[m].copy()
        prev = par
    if lib.mobile:
        _hold_base(out, states, lib.base_arm, arms, shifts)
    missing = [v for v in variables if v not in out]
    if missing:
        log.warning("no initial value for %s", missing[:5])
    return out


def _keyframe_ik(
    lib: FactorLib, ik: TopIK, arm: str, top: FloatArray, q_ref: FloatArray, col_key: tuple[str, ...] | None = None
) -> tuple[bool, FloatArray]:
    """The IK of a keyframe: a mobile arm first with its base kept where it stands (as ``EqualBase`` will
    keep it since the last end-move), else anywhere (the guess of a plan that needs another base).
    ``col_key``: its ``ColFix`` factor (``TopIK._solver``)."""
    if lib.mobile:
        ok, q = ik.solve(arm, top, q_ref, fixed_base=True, col_key=col_key)
        if ok:
            return ok, q
    return ik.solve(arm, top, q_ref, col_key=col_key)


def _share_base(lib: FactorLib, q: dict[str, FloatArray], arm: str) -> None:
    """The base ``arm``'s keyframe IK chose, in every arm's variable in ``q`` (arms riding one base)."""
    if lib.mobile:
        for m in q:
            q[m][:3] = q[arm][:3]


def _hold_base(
    out: dict[Var, FloatArray], states: Sequence[SymbolicState], mover: str, arms: Sequence[str],
    shifts: Mapping[int, FloatArray] | None = None,
) -> None:
    """The base of the mobile arm ``mover`` (and of the ``arms`` that ride it) in ``out`` made constant over
    each stretch of states in which it is not moving (as ``EqualBase`` and ``SameBase`` will hold it): the
    base of the stretch's first keyframe of any arm (the IK chose it to reach there; the start's for the
    first stretch); a state in which it moves takes the next stretch's. ``shifts``: t -> the xy move (2,)
    [m] of a drawer's drive into state t, which the base follows."""
    moved = np.zeros((len(states), 2))  # the drives' moves summed up to each state
    for t in range(1, len(states)):
        moved[t] = moved[t - 1] + (shifts or {}).get(t, 0.0)
    runs: list[list[int]] = []
    for t, s in enumerate(states):
        if moving(mover) in s:
            continue
        if runs and runs[-1][-1] == t - 1:
            runs[-1].append(t)
        else:
            runs.append([t])
    for k, run in enumerate(runs):
        t_ref, m_ref = run[0], mover
        if run[0] > 0:
            changed = ((t, m) for t in run[1:] for m in arms
                       if not np.allclose(out[Var("q", m, t)], out[Var("q", m, t - 1)]))
            t_ref, m_ref = next(changed, (run[0], mover))
        base = out[Var("q", m_ref, t_ref)][:3].copy()
        base[:2] -= moved[t_ref]  # the stretch's base before its drives
        end = runs[k + 1][0] if k + 1 < len(runs) else len(states)
        for t in range(run[0], end):  # the stretch, then the moving states after it take the next base
            for m in arms:
                out[Var("q", m, t)][:3] = base
                out[Var("q", m, t)][:2] += moved[min(t, run[-1])]
        if k > 0:  # the moving states before the stretch
            for t in range(runs[k - 1][-1] + 1, run[0]):
                for m in arms:
                    out[Var("q", m, t)][:3] = base
                    out[Var("q", m, t)][:2] += moved[run[0]]


def ik_seed(
    lib: FactorLib, ik: TopIK, factors: Sequence[Factor], guess: Mapping[Var, FloatArray], bearing: int = 0
) -> dict[Var, FloatArray]:
    """``guess`` with each kinematic switch's arm at a top-grasp IK of its object's guessed world pose
    (and the held pose that matches): a start for a subgraph whose guess later solves have moved.
    ``bearing`` k > 0 (a mobile arm): the IK starts with the base at the k-th of ``_ring_starts``' bearings
    round the object (nearest the guess's base first), not at the guess's: from the guess's base the IK
    stops at the first posture that reaches (often at the tilt bound, the fingers off the faces), where
    the subgraph's solve fails again; the other bearings give other bases and postures. The held pose goes
    to every variable an ``Equal`` chain ties to the switch's (the solver starts the chain from its earliest
    one: a place's seeded grasp was otherwise lost to the stale one where the pick left it). On robots whose
    arms share a driven base (``FactorLib.riders``) the new base goes to every arm variable the subgraph
    ties to it (``EqualBase``, ``SameBase``: a start with the other arm, or the posture before the pick, at
    the old base fails), and a later switch on a base so set first tries to reach from it (not on the
    one-armed HSR, where the same starts lose conflicts' refutations)."""
    out = dict(guess)
    cols = {f.vars[0]: f.key for f in factors if f.kind == "ColFix" and len(f.key) > 2}  # drawer-tagged ones
    based: set[Var] = set()  # the arm variables whose base a switch's IK below set
    for f in factors:
        if f.kind != "Kin":
            continue
        q_var, w_var, r_var = f.vars
        o, arm = f.key[1], f.key[2]
        w = np.asarray(out[w_var], float)
        h = lib.objects[o].size[2]
        top = w[:3] + np.array([0.0, 0.0, h / 2 - min(0.025, h / 2)])
        q_ref = np.asarray(out[q_var], float)
        ok = False
        if q_var in based:  # a base an earlier switch of this subgraph chose: kept if the arm reaches from it
            ok, q = ik.solve(arm, top, q_ref, fixed_base=True, col_key=cols.get(q_var))
        if not ok:
            if bearing > 0 and lib.mobile:
                home = lib.home_q(arm)
                home[:3] = q_ref[:3]
                rings = _ring_starts(home, top, q_ref)
                q_ref = rings[(bearing - 1) % len(rings)]
            ok, q = ik.solve(arm, top, q_ref, col_key=cols.get(q_var))
        if ok:
            out[q_var] = q
            held = _held_of(lib, arm, q, w)
            for v in _tied(factors, r_var, ("Equal",)):  # the solver starts an Equal chain at its earliest value
                out[v] = held.copy()
            if lib.riders:  # the arms that share this base in the subgraph (EqualBase, SameBase) go with it
                tied = _tied(factors, q_var, ("EqualBase", "SameBase"))
                for v in tied - {q_var}:
                    out[v] = np.r_[q[:3], np.asarray(out[v], float)[3:]]
                based |= tied
    return out


def _tied(factors: Sequence[Factor], start: Var, kinds: tuple[str, ...]) -> set[Var]:
    """The variables the subgraph's factors of ``kinds`` tie to ``start`` (``start`` included): ``Equal``
    for an object's pose carried on, ``EqualBase`` and ``SameBase`` for the arm variables on one base."""
    edges = [f.vars for f in factors if f.kind in kinds]
    tied, grew = {start}, True
    while grew:
        grew = False
        for a, b in edges:
            if (a in tied) != (b in tied):
                tied |= {a, b}
                grew = True
    return tied
