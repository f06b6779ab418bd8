"""Level 3 of LGP: full-path optimisation between fixed keyframes, one sparse NLP per segment.

Each segment is a guided path of the plan (the reachability graph's waypoints, getWaypoints, or a
transport / drive-round chain) between two configurations fixed by level 2 (the keyframes' approach
configurations): it is resampled to ``T`` waypoints (equal time at the model's velocity limits) and
the ``T - 2`` inner ones are the variables. With the ends fixed the segments share no variable, so
the whole-path NLP is block diagonal: solving it at once or segment by segment gives the same optimum
(the keyframes act as the kinematic switches, fixed from level 2). It is solved segment by segment, one
IPOPT problem each (``_solve``): each takes the iterations it needs, not those of the hardest segment
(at once, every IPOPT iteration would factorise all of them), and a re-solve
adds rows to the segment that violated them only. Offline, the segments may be solved in two processes
(``default_workers``, ``planning.forked``: half in a forked child, the results the same bit for bit).
Variables time-major (waypoint by waypoint, z = [x, y, yaw, q_arm, a moving torso] each), the rows
time-major too, so the constraint Jacobian (block bidiagonal) and the Lagrangian's Hessian (banded)
grow linearly with the segment; both are assembled from that structure (``_nlp``, which takes any set
of segments).

At every inner waypoint and at the midpoint of every step (``_checkpoints``), built from the shared
factors (``nlp.factors``, ``nlp.hand``), the same the keyframe NLP and GNPP use:

* arm spheres and the open fingers' spheres clear of world boxes (fixtures, drawers at their
  openings, the objects where they stand) by ``MARGIN``; a held object (kinematic switch: fixed in
  the tool frame for the segment, ``T_tool_obj``) as spheres covering its box, clear of them too;
* the arm's spheres off the body it is mounted on (self-collision proxy); the base footprint off
  fixture footprints and open drawers;
* joint position limits (bounds) and per-step velocity limits |z_t - z_{t-1}| <= v_max dt, dt the
  segment's step time (``SLACK`` times what the warm start needs at full speed);
* a trust region: each arm joint within the warm start's range over the segment (+ ``PAD``): the
  hand against its own forearm (adjacent links) is not modelled, and a straight line between the
  ends, what the objective pulls towards, lies inside that range anyway (``PAD_STRICT`` for a
  ``strict`` segment, a straight move that may have to detour round an obstacle: the replay checks
  the hand against the forearm).

Objective: the weighted squared second differences (acceleration), base weighing ``W_BASE``.
Rows far from active (slack > ``CUTOFF``) at the warm start and on the straight line between the
ends are left out; in a large block (``PRUNE_MIN``) a kept row is in the NLP only at the checkpoints
where it is near active on either (and the checkpoints either side). The solution is checked against
every row at every checkpoint and a re-solve adds the violated ones, at every checkpoint.
A row the warm start itself violates at a checkpoint (the spheres are conservative proxies of meshes
the exact checker passed) is bounded there by the warm start's value instead (``relaxed``): never
worse than the guide.
"""

from __future__ import annotations

import enum
import functools
import itertools
import logging
import os
import time
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse

from rlgp_exec.errors import RlgpError
from rlgp_exec.ipopt import LEAN
from rlgp_exec.planning import budget
from rlgp_exec.planning.forked import Result, fork_map
from rlgp_exec.planning.margins import BASE_MARGIN, FEAS_TOL
from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows, box_clear, footprint_clear
from rlgp_exec.planning.nlp.hand import _box_cover, cover_refusal, points_clear, self_rows_function
from rlgp_exec.planning.nlp.keyframes import W_BASE
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene.geometry import Box

__all__ = ["PathResult", "PathStatus", "Segment", "optimize_paths", "resample"]

log = logging.getLogger(__name__)
T_DEFAULT = 12  # waypoints per segment, ends included (with the step midpoints: 21 checkpoints)
MARGIN = 0.01  # [m] spheres keep this from the world boxes
SLACK = 1.5  # the step time is this times the warm start's (per-step velocity bound)
CUTOFF = 0.05  # [m] rows with more slack than this all along the warm start are left out
# kept rows x checkpoints from which a row is left out at the checkpoints where it is far (``_Block.on``):
# a long base move's block solves faster pruned; the HSR's smaller segments lose more to the re-solves that
# put rows back than the smaller NLP saves (their optima leave both the guide and the line)
PRUNE_MIN = 600
REACH = 0.3  # [m] how far past a sphere's centre or the tool the robot reaches (radius, fingers, held object)
PAD = 0.05  # [rad or m] an arm joint stays within the warm start's range widened by this
PAD_STRICT = 0.3  # ... for a ``strict`` segment: a straight move has no detour in its range to keep to
PROCESSES_ENV = "RLGP_EXEC_L3_PROCESSES"  # 1 or 2: how many processes solve segments at once


def default_workers() -> int:
    """Processes level 3 solves segments in (``planning.forked``): ``$RLGP_EXEC_L3_PROCESSES`` if set, else
    1. Two take the machine's other core, which on the robot's PC is the HAL's and perception's (the CAN
    fuzz test's heartbeat went stale beside planning tests that forked): for offline planning only."""
    value = os.environ.get(PROCESSES_ENV)
    if value is None:
        return 1
    try:
        return max(1, int(value))
    except ValueError:
        raise RlgpError(f"{PROCESSES_ENV}={value!r}: not a number of processes (1 or 2)") from None


ROUNDS = 2  # solves per segment at most (re-solves add rows the solution violates)
# IPOPT's tolerance (feasibility is FEAS_TOL's, checked on every row after the solve): the fastest, with
# paths within 2 % of the cost of tighter ones, and not ending as near the clearance rows' MARGIN
TOL = 1e-3
# the warm start is the guide, feasible but for the relaxed rows: IPOPT starts at it, not pushed 1 % of each
# bound's range inside (its default), for fewer iterations to the same optima. A re-solve (rows added that
# the last solution violates) keeps the default push: from near its active rows the small push is slower
BOUND_PUSH = 1e-6


class PathStatus(enum.Enum):
    OK = "ok"
    INFEASIBLE = "infeasible"  # IPOPT ended with constraints violated
    WORSE = "worse"  # feasible but costlier than the warm start (kept out)
    REFUSED = "refused"  # not optimised: its held object has no sphere cover within the cap (``nlp.hand``)


@dataclass(frozen=True)
class Segment:
    """One guided path to optimise and the world it moves through (all world frame)."""

    warm: FloatArray  # (m, nq) m >= 2 configurations; warm[0] and warm[-1] are the fixed ends
    boxes: tuple[Box, ...]  # obstacles: fixtures, drawers at their openings, standing objects
    footprints: tuple[tuple[FloatArray, FloatArray], ...] = ()  # (T (4, 4), size (3,)) the base avoids
    held: tuple[FloatArray, FloatArray] | None = None  # (size (3,) [m], T_tool_obj (4, 4)) carried
    fix_base: bool = False  # the base stays where warm[0] has it (an arm's move at a fixed base)
    # the warm start is not known to be collision-free (GNPP's straight moves): a row is relaxed only to
    # its value at the fixed ends, and the result is kept when feasible even if costlier than the warm start
    strict: bool = False


@dataclass(frozen=True)
class PathResult:
    """Level 3's outcome, segment by segment: a segment whose NLP failed (``PathStatus``) keeps its warm
    start (resampled), the others are optimised."""

    statuses: tuple[PathStatus, ...]  # per segment
    paths: tuple[FloatArray, ...]  # per segment (T, nq) [m, rad], wrapped: optimised where ok, else the warm start
    acc_costs: tuple[float, ...]  # per segment: the objective at the path returned
    warm_acc_costs: tuple[float, ...]  # per segment: the objective at the resampled warm start
    violation: float  # largest constraint violation of a solution [m or rad] (kept or not)
    durations_s: tuple[float, ...]  # per segment: (T - 1) dt [s] at which the velocity bounds hold
    n_var: int  # summed over the segments' NLPs
    n_con: int
    jac_nnz: int  # non-zeros of the constraint Jacobians
    relaxed: int  # rows bounded by the warm start's value (violated there already)
    iterations: int  # IPOPT's, all segments
    build_s: float  # summed over the segments (in two processes they overlap)
    solve_s: float
    reason: str  # "ok", or why each failed segment did
    wall_s: float = 0.0  # the call's own time [s]

    @property
    def optimised(self) -> tuple[bool, ...]:
        """Per segment: whether its path is level 3's."""
        return tuple(s is PathStatus.OK for s in self.statuses)

    @property
    def ok(self) -> bool:
        """Every segment optimised."""
        return all(self.optimised)

    @property
    def acc_cost(self) -> float:
        return float(sum(self.acc_costs))

    @property
    def warm_acc_cost(self) -> float:
        return float(sum(self.warm_acc_costs))


def _unwrapped(model: RobotModel, idx: FloatArray, path: FloatArray) -> FloatArray:
    """(m, n) the path's base + arm coordinates, continuous joints unwrapped (the short way, as the
    replay interpolates)."""
    z = [np.asarray(path[0], float)[idx]]
    for a, b in itertools.pairwise(path):
        z.append(z[-1] + model.limits.difference(b, a)[idx])
    return np.array(z)


def resample(z: FloatArray, vmax: FloatArray, T: int) -> tuple[FloatArray, float]:
    """A piecewise-linear path z (m, n) resampled to T points equally spaced in time at full speed
    (step time max_j |dz_j| / vmax_j); returns (T, n) and the step time [s]."""
    step_t = np.max(np.abs(np.diff(z, axis=0)) / vmax, axis=1)
    s = np.r_[0.0, np.cumsum(step_t)]
    if s[-1] <= 0.0:
        return np.repeat(z[:1], T, axis=0), 0.0
    targets = np.linspace(0.0, s[-1], T)
    out = np.array([np.interp(targets, s, z[:, j]) for j in range(z.shape[1])]).T
    out[0], out[-1] = z[0], z[-1]
    return out, float(s[-1] / (T - 1))


def _acc_cost(Z: FloatArray, w: FloatArray) -> float:
    """Σ_t Σ_j w_j (z_{t+1} - 2 z_t + z_{t-1})_j^2 of a path Z (n, T)."""
    acc = Z[:, 2:] - 2 * Z[:, 1:-1] + Z[:, :-2]
    return float(np.sum(w[:, None] * acc**2))


@functools.lru_cache(maxsize=16)
def _acc_operators(w: tuple[float, ...], m: int) -> tuple[FloatArray, FloatArray, ca.DM]:
    """For a block of m inner waypoints (n,) between fixed ends, time-major: L (n m, n m), the second
    differences of the inner waypoints (the accelerations are L x + e, e the ends' part), the weights
    (n m,) of ``_acc_cost`` at every step (both read-only), and its Hessian 2 L' diag(weights) L (banded,
    as a sparse DM: converting the dense (n m, n m) array cost ~1 ms a segment)."""
    D2 = np.diag(np.full(m, -2.0)) + np.diag(np.ones(m - 1), 1) + np.diag(np.ones(m - 1), -1)
    L = np.kron(D2, np.eye(len(w)))
    weights = np.tile(np.asarray(w, float), m)
    for a in (L, weights):
        a.flags.writeable = False
    H = 2.0 * L.T @ (weights[:, None] * L)
    return L, weights, ca.DM(scipy.sparse.csc_matrix(H))


def _acc_quadratic(
    w: FloatArray, m: int, ends: Sequence[tuple[FloatArray, FloatArray]]
) -> tuple[ca.DM, FloatArray, float]:
    """The summed ``_acc_cost`` of blocks of m inner waypoints between fixed ends (z_0, z_T) (n,) each, as
    0.5 x' H x + b' x + c in x = the blocks' inner waypoints (block by block, time-major): (H (sparse),
    b, c), from the accelerations L x + e (e: z_0 at the first step, z_T at the last)."""
    n = len(w)
    L, weights, Hb = _acc_operators(tuple(float(v) for v in w), m)
    b, c = [], 0.0
    for z0, zT in ends:
        e = np.zeros(n * m)
        e[:n] += z0
        e[-n:] += zT
        b.append(2.0 * L.T @ (weights * e))
        c += float(e @ (weights * e))
    return ca.diagcat(*[Hb] * len(ends)), np.concatenate(b), c


def _held_spheres(held: tuple[FloatArray, FloatArray] | None) -> list[tuple[FloatArray, float]]:
    """Spheres (centre in the tool frame (3,), radius) covering a held box (``nlp.hand._box_cover``)."""
    if held is None:
        return []
    size, T_tool_obj = held
    return [((T_tool_obj @ np.r_[c, 1.0])[:3], r) for c, r in _box_cover(np.asarray(size, float))]


def _rows(model, rs: RobotSymbols, seg: Segment, hand, self_rows: tuple[ca.SX, FloatArray]) -> Rows:
    """Every collision row of one waypoint of ``seg`` (``rs``: the robot at the symbolic z = base, arm, the
    ``extra`` joints, the other joints where ``seg.warm[0]`` has them; ``self_rows``: its self-clearance
    rows at z and their lower bounds)."""
    rows = Rows.empty()
    boxes = _near(model, rs, seg)
    box_clear(rs, boxes, rows, margin=MARGIN)
    points_clear(rs.T_tool, [*hand, *_held_spheres(seg.held)], boxes, rows, margin=MARGIN)
    rows.add_all(self_rows[0], self_rows[1], ca.inf)
    footprint_clear(rs, list(seg.footprints), rows, margin=BASE_MARGIN)
    return rows


def _near(model, rs: RobotSymbols, seg: Segment) -> list[Box]:
    """The boxes of ``seg`` within REACH + CUTOFF of an arm sphere's centre or the tool at some
    warm-start waypoint: the rest cannot come near active and their rows are never built."""
    frames = list(dict.fromkeys([rs.manip.tool_frame, *(f for f, _ in rs.spheres)]))
    pts = np.array([T[:3, 3] for q in seg.warm for T in model.fk_many(q, frames)])  # one FK pass per waypoint
    out = []
    for b in seg.boxes:
        local = (np.linalg.inv(b.T) @ np.c_[pts, np.ones(len(pts))].T)[:3].T
        d = np.linalg.norm(np.maximum(np.abs(local) - np.asarray(b.size) / 2, 0.0), axis=1).min()
        if d < REACH + CUTOFF:
            out.append(b)
    return out


@dataclass
class _Block:
    """A segment's part of the NLP: its step function (waypoint rows kept + velocity) and bounds."""

    Zw: FloatArray  # (T, n) resampled warm start
    dt: float
    lo: FloatArray  # (T - 2, n) bounds of the inner waypoints: joint limits, the arm within the warm start's
    hi: FloatArray  # range, ``_waypoint_bounds``
    g_all: ca.Function  # z -> every collision row
    lb_all: FloatArray
    g_expr: list[ca.SX]
    z: ca.SX
    zp: ca.SX
    keep: np.ndarray  # (k,) int: indices of the rows in the NLP
    lb: FloatArray  # (len(keep), 2 T - 3) their lower bounds per checkpoint (``_checkpoints``; relaxed where
    # the warm start violates them)
    relaxed: int
    # (len(keep), 2 T - 3) bool: the checkpoints at which each kept row is in the NLP: in a block of PRUNE_MIN rows
    # x checkpoints or more, where it is near active at the warm start or on the line (and either side); else all
    on: np.ndarray
    # a segment whose warm start is a straight move (resampled: zero acceleration cost, the objective's least)
    # satisfying every row at every checkpoint (as bounded here: a segment that is not strict has its rows
    # relaxed to the warm start): that is the optimum, left out of the NLP. IPOPT from it ended up to ~1e-4
    # above it (its tolerance) after 74-93 iterations, and the segment then counted as costlier than its warm
    # start (table_clearing_hsr's first segment, a straight approach to the knob, in every plan)
    settled: bool = False


def _checkpoints(Z: FloatArray) -> FloatArray:
    """(2 T - 3, n) where a path Z (T, n) is checked, in time order: the midpoint of every step and every
    inner waypoint (mid 0-1, waypoint 1, mid 1-2, ..., waypoint T-2, mid T-2 - T-1). The midpoints catch
    what a waypoint-only check lets a step cut through (a base passing a cabinet's corner)."""
    mids = (Z[1:] + Z[:-1]) / 2
    out = np.empty((2 * len(Z) - 3, Z.shape[1]))
    out[0::2], out[1::2] = mids, Z[1:-1]
    return out


def _block(model, rs: RobotSymbols, self_rows: tuple[ca.SX, FloatArray], idx, seg, T, hand) -> _Block:
    """Resample ``seg``'s warm start and build its rows; keep those near active (module docstring)."""
    n = len(idx)
    zs = _unwrapped(model, idx, seg.warm)
    vmax = model.limits.velocity[idx]
    Zw, tau = resample(zs, vmax, T)
    z, zp = rs.z, ca.SX.sym("zp", n)
    rows = _rows(model, rs, seg, hand, self_rows)
    g_all = ca.Function("g_all", [z], [ca.vertcat(*rows.g)] if rows.g else [ca.SX(0, 1)])
    lb_all = np.asarray(rows.lower, float)
    lo, hi = model.limits.lower[idx].copy(), model.limits.upper[idx].copy()
    lo[model.limits.continuous[idx]], hi[model.limits.continuous[idx]] = -np.inf, np.inf
    pad = PAD_STRICT if seg.strict else PAD
    lo[3:], hi[3:] = np.maximum(lo[3:], zs[:, 3:].min(axis=0) - pad), np.minimum(hi[3:], zs[:, 3:].max(axis=0) + pad)
    if seg.fix_base:
        lo[:3] = hi[:3] = zs[0, :3]
    lo_w, hi_w = _waypoint_bounds(model, idx, lo, hi, Zw[1:-1])
    pts = _checkpoints(Zw)
    blk = _Block(Zw, SLACK * tau, lo_w, hi_w, g_all, lb_all, list(rows.g), z, zp, np.zeros(0, int),
                 np.zeros((0, len(pts))), 0, np.zeros((0, len(pts)), bool))
    if len(lb_all):
        vals = np.asarray(g_all.map(len(pts))(pts.T)).reshape(len(lb_all), -1)
        # near active at the warm start or on the straight line between the ends (where the
        # objective pulls), checkpoint by checkpoint: where the solution is likely to meet them
        line = _checkpoints(Zw[0] + np.linspace(0.0, 1.0, T)[:, None] * (Zw[-1] - Zw[0]))
        on_line = np.asarray(g_all.map(len(line))(line.T)).reshape(len(lb_all), -1)
        keep = np.flatnonzero(np.minimum(vals.min(axis=1), on_line[:, 1::2].min(axis=1)) - lb_all < CUTOFF)
        near = np.minimum(vals, on_line)[keep] - lb_all[keep, None] < CUTOFF
        blk.on = _widened(near) if near.size >= PRUNE_MIN else np.ones_like(near)
        if seg.strict:  # never below the fixed ends (a row they violate: the spheres' conservatism)
            ends = np.asarray(g_all.map(2)(Zw[[0, -1]].T)).reshape(len(lb_all), 2).min(axis=1)
            lb = np.repeat(np.minimum(lb_all, ends - 1e-6)[keep, None], len(pts), axis=1)
        else:  # per checkpoint: never below the warm start
            lb = np.minimum(lb_all[keep, None], vals[keep] - 1e-6)
        blk.keep, blk.lb, blk.relaxed = keep, lb, int(np.sum(lb < lb_all[keep, None]))
    # the rows not kept clear their bounds by CUTOFF at the warm start's checkpoints (``low``)
    clear = not len(lb_all) or bool(np.all(vals[blk.keep] >= blk.lb))
    blk.settled = clear and _straight(Zw)
    return blk


def _widened(on: np.ndarray) -> np.ndarray:
    """(k, c) bool: ``on`` (k, c) (rows x checkpoints in time order) and each checkpoint's neighbours (half a
    step before and after): the solution's checkpoint lies between the warm start's and the line's, not
    always at the same time."""
    out = on.copy()
    out[:, 1:] |= on[:, :-1]
    out[:, :-1] |= on[:, 1:]
    return out


def _waypoint_bounds(
    model, idx, lo: FloatArray, hi: FloatArray, inner: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """(T - 2, n) bounds of the inner waypoints: ``lo``/``hi`` (n,) at each, a joint with ``keyframe_limits``
    (where the hand leaves the arm's own links: the PR2's wrist flex, its fingers in the forearm beyond
    -1.75 rad) kept within them, or no further out than the warm start ``inner`` (T - 2, n) is at that
    waypoint. The tucked PR2 starts at -1.85 rad; level 3 kept the wrist there while it rolled (the guide
    flexes it back first), the fingers met the forearm, and the replay put the segment back to its
    guide (pick_place_pr2 seeds 16 and 17, sorting_pr2 seed 1)."""
    lo_w, hi_w = np.tile(lo, (len(inner), 1)), np.tile(hi, (len(inner), 1))
    for j, i in enumerate(idx):
        narrow = model.config.keyframe_limits.get(model.joint_names[int(i)])
        if narrow is not None:
            lo_w[:, j] = np.maximum(lo_w[:, j], np.minimum(narrow[0], inner[:, j]))
            hi_w[:, j] = np.minimum(hi_w[:, j], np.maximum(narrow[1], inner[:, j]))
    return lo_w, hi_w


def _straight(Z: FloatArray) -> bool:
    """Whether the path Z (T, n) has no acceleration: equal steps along one line [m or rad]."""
    acc = Z[2:] - 2 * Z[1:-1] + Z[:-2]
    return bool(np.all(np.abs(acc) <= 1e-9))


@functools.lru_cache(maxsize=16)
def _selectors(n: int, m: int) -> tuple[ca.DM, ca.DM]:
    """Constant sparse maps from a segment's inner waypoints x = vec(Z_inner) (n m,) to its m + 1 step
    midpoints (0.5 I on both neighbours; the fixed ends add a constant) and to its m + 1 steps
    z_{t+1} - z_t (I, -I)."""
    S, D = np.zeros((n * (m + 1), n * m)), np.zeros((n * (m + 1), n * m))
    eye = np.eye(n)
    for t in range(m + 1):
        rows = slice(t * n, (t + 1) * n)
        if t >= 1:
            S[rows, (t - 1) * n:t * n], D[rows, (t - 1) * n:t * n] = 0.5 * eye, -eye
        if t < m:
            S[rows, t * n:(t + 1) * n], D[rows, t * n:(t + 1) * n] = 0.5 * eye, eye
    return ca.sparsify(ca.DM(S)), ca.sparsify(ca.DM(D))


def _nlp(model, blocks: list[_Block], idx, w, T: int, max_iter: int, at_guide: bool = True):
    """The whole-path NLP of ``blocks``: (solver, x, g, x0, lbx, ubx, lbg, ubg). Variables time-major;
    a segment's rows: its collision rows at the step midpoints, at the waypoints, then its velocity
    rows, each group time-major. IPOPT gets both derivatives assembled from their structure: the
    constraint Jacobian from one dense (k, n) block per checkpoint (``jat``, mapped) placed on the
    block diagonal (midpoints: through the constant selector); the Hessian of the Lagrangian is the
    objective's alone (constant, banded; the collision rows' curvature left out, as sequential
    convexification does: the exact one cost ~4x the time per solve for the same paths on
    pick_place_pr2)."""
    n, m = len(idx), T - 2
    S, D = _selectors(n, m)
    X, G, J, lbg, ubg, x0, lbx, ubx = [], [], [], [], [], [], [], []
    for b in blocks:
        Zi = ca.MX.sym("Z", n, m)
        X.append(ca.vec(Zi))
        Zfull = ca.horzcat(ca.DM(b.Zw[0]), Zi, ca.DM(b.Zw[-1]))
        Mid = (Zfull[:, 1:] + Zfull[:, :-1]) / 2
        g_kept = ca.vertcat(*[b.g_expr[i] for i in b.keep]) if len(b.keep) else ca.SX(0, 1)
        k = int(g_kept.numel())
        at = ca.Function("at", [b.z], [g_kept])
        jat = ca.Function("jat", [b.z], [ca.jacobian(g_kept, b.z)])
        # a row's values at every checkpoint (time-major: row r at checkpoint t is entry t k + r), of which
        # the NLP takes those ``on``
        mid, way = np.flatnonzero(b.on[:, 0::2].T.reshape(-1)), np.flatnonzero(b.on[:, 1::2].T.reshape(-1))
        G += [ca.vec(at.map(m + 1)(Mid))[mid.tolist()], ca.vec(at.map(m)(Zi))[way.tolist()],
              ca.vec(Zfull[:, 1:] - Zfull[:, :-1])]
        if k:
            J_mid = ca.mtimes(ca.diagcat(*ca.horzsplit(jat.map(m + 1)(Mid), n))[mid.tolist(), :], ca.MX(S))
            J_way = ca.diagcat(*ca.horzsplit(jat.map(m)(Zi), n))[way.tolist(), :]
        else:
            J_mid, J_way = ca.MX(0, n * m), ca.MX(0, n * m)
        J.append(ca.vertcat(J_mid, J_way, ca.MX(D)))
        vel = model.limits.velocity[idx] * b.dt
        lbg += [*b.lb[:, 0::2].T.reshape(-1)[mid], *b.lb[:, 1::2].T.reshape(-1)[way], *np.tile(-vel, m + 1)]
        ubg += [*np.full(mid.size + way.size, np.inf), *np.tile(vel, m + 1)]
        x0.append(b.Zw[1:-1].reshape(-1))
        lbx.append(b.lo.reshape(-1))
        ubx.append(b.hi.reshape(-1))
    x, g = ca.vertcat(*X), ca.vertcat(*G)
    jac = ca.diagcat(*J)
    # the objective is quadratic: 0.5 x' H_f x + b' x + c, its Hessian a constant; IPOPT gets it in that
    # form (its gradient through the MX graph of the accelerations took ~2.4 ms per evaluation, ~15 % of
    # a pick_place_pr2 solve), assembled from its operators (``_acc_quadratic``), not differentiated
    H_f, b_f, c_f = _acc_quadratic(w, m, [(b.Zw[0], b.Zw[-1]) for b in blocks])
    f = 0.5 * ca.bilin(ca.MX(H_f), x, x) + ca.dot(ca.MX(ca.DM(b_f)), x) + c_f
    lam_f, p, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("p", 0), ca.MX.sym("lam_g", g.numel())
    hess_lag = ca.Function("hess_lag", [x, p, lam_f, lam_g], [ca.triu(lam_f * ca.MX(H_f))])
    jac_g = ca.Function("jac_g", [x, p], [g, jac])
    opts: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": max_iter,
            "ipopt.tol": TOL, "ipopt.mu_init": 1e-3, "ipopt.hessian_constant": "yes", "hess_lag": hess_lag,
            **({"ipopt.warm_start_init_point": "yes", "ipopt.bound_push": BOUND_PUSH, "ipopt.bound_frac": BOUND_PUSH}
               if at_guide else {}),
            "jac_g": jac_g}
    solver = ca.nlpsol("path", "ipopt", {"x": x, "f": f, "g": g}, {**opts, **LEAN, **budget.ipopt_stop()})
    return (solver, x, g, jac, np.concatenate(x0), np.concatenate(lbx), np.concatenate(ubx),
            np.asarray(lbg, float), np.asarray(ubg, float))


def optimize_paths(
    model: RobotModel,
    segments: Sequence[Segment],
    T: int = T_DEFAULT,
    manipulator: str | None = None,
    hand: Sequence[tuple[FloatArray, float]] = (),
    self_spheres: Sequence[tuple[str, FloatArray, float]] = (),
    body: Sequence[tuple[str, Box]] = (),
    max_iter: int = 200,
    workers: int | None = None,
) -> PathResult:
    """Optimise every segment's path, each its own NLP (module docstring), ``workers`` processes at once
    (``planning.forked``; default ``default_workers()``). ``hand``: finger spheres (tool frame,
    ``nlp.hand.finger_spheres``); ``self_spheres``/``body``: the self-collision proxy
    (``nlp.hand.arm_link_spheres``, ``nlp.hand.body_obstacles``; their rows are built once per model and
    arguments, ``nlp.hand.self_rows_function``). T >= 3."""
    if T < 3:
        raise ValueError(f"optimize_paths: T must be at least 3, got {T}")
    t0 = time.perf_counter()
    manip = model.manipulator(manipulator)
    core = [*model.group("base"), *model.group(manip.group)]
    moving = {int(j) for s in segments for j in np.flatnonzero(np.ptp(np.asarray(s.warm), axis=0) > 1e-9)}
    extra = tuple(sorted(moving - set(core)))  # e.g. the PR2's torso, raised for a transport
    idx = np.array([*core, *extra], dtype=int)
    n = len(idx)
    w = np.r_[np.full(3, W_BASE), np.ones(n - 3)]
    # per segment: the other joints (another arm's posture) where its warm start has them. The robot's
    # symbols at z and its self-clearance rows (forward kinematics, ~200 rows on the PR2: ~20 ms a
    # segment) are built once for the segments that agree on those joints
    z = ca.SX.sym("z", n)
    shared: dict[bytes, tuple[RobotSymbols, tuple[ca.SX, FloatArray]]] = {}

    def shared_of(q0: FloatArray) -> tuple[RobotSymbols, tuple[ca.SX, FloatArray]]:
        fixed = np.array(q0, float)
        fixed[idx] = 0.0
        key = fixed.tobytes()
        if key not in shared:
            self_rows = self_rows_function(model, self_spheres, body)
            rs = RobotSymbols(model, q0, manip.name, z, extra, frames=self_rows.frames)
            shared[key] = (rs, (self_rows.rows(rs), self_rows.lower))
        return shared[key]

    def one(k: int) -> Result:
        """Segment k's block and, unless it is settled, its solve (in this process or ``fork_map``'s child)."""
        t1 = time.perf_counter()
        seg = segments[k]
        budget.check()
        refused = cover_refusal(seg.held[0]) if seg.held is not None else None
        if refused is not None:  # its guide is kept
            Zr, tau = resample(_unwrapped(model, idx, seg.warm), model.limits.velocity[idx], T)
            return {"Zw": Zr, "dt": SLACK * tau, "relaxed": 0, "settled": False, "warm": _acc_cost(Zr.T, w),
                    "rows_s": time.perf_counter() - t1, "refused": f"held object: {refused}"}
        b = _block(model, *shared_of(seg.warm[0]), idx, seg, T, hand)
        out: Result = {"Zw": b.Zw, "dt": b.dt, "relaxed": b.relaxed, "settled": b.settled,
                       "warm": _acc_cost(b.Zw.T, w), "rows_s": time.perf_counter() - t1}
        if not b.settled:
            r = _solve(model, [b], idx, w, T, max_iter)
            out.update(Z=r.paths[id(b)], cost=r.cost, violation=r.violation, status=r.status,
                       iterations=r.iterations, n_var=r.n_var, n_con=r.n_con, jac_nnz=r.jac_nnz,
                       build_s=r.build_s, solve_s=r.solve_s)
        return out

    results = fork_map(one, range(len(segments)), default_workers() if workers is None else workers)
    build_s = solve_s = viol = 0.0
    iterations = n_var = n_con = jac_nnz = 0
    Zs, statuses, costs, warm_costs, reasons = [], [], [], [], []
    for k, (seg, r) in enumerate(zip(segments, results, strict=True)):
        Zw, warm = _array(r["Zw"]), _number(r["warm"])
        warm_costs.append(warm)
        build_s += _number(r["rows_s"])
        if r["settled"] or "refused" in r:  # optimal as it is (``_Block.settled``), or not optimised
            Zs.append(Zw)
            statuses.append(PathStatus.REFUSED if "refused" in r else PathStatus.OK)
            costs.append(warm)
            if "refused" in r:
                reasons.append(f"segment {k}: {r['refused']}")
            continue
        build_s, solve_s = build_s + _number(r["build_s"]), solve_s + _number(r["solve_s"])
        iterations, n_var = iterations + int(_number(r["iterations"])), n_var + int(_number(r["n_var"]))
        n_con, jac_nnz = n_con + int(_number(r["n_con"])), jac_nnz + int(_number(r["jac_nnz"]))
        cost, violation = _number(r["cost"]), _number(r["violation"])
        viol = max(viol, violation)
        if violation > FEAS_TOL:
            status, why = PathStatus.INFEASIBLE, f"constraints violated by {violation:.2e} ({r['status']})"
        elif cost > warm + 1e-9 and not seg.strict:
            status, why = PathStatus.WORSE, f"acceleration cost {cost:.3g} > warm start's {warm:.3g}"
        else:
            status, why = PathStatus.OK, ""
        statuses.append(status)
        kept = status is PathStatus.OK
        Zs.append(_array(r["Z"]) if kept else Zw)
        costs.append(cost if kept else warm)
        if not kept:
            reasons.append(f"segment {k}: {why}")
    paths = []
    for seg, Z in zip(segments, Zs, strict=True):
        q = np.repeat(np.asarray(seg.warm[:1], float), len(Z), axis=0)
        q[:, idx] = Z
        paths.append(np.array([model.limits.wrap(qi) for qi in q]))
    return PathResult(
        tuple(statuses), tuple(paths), tuple(costs), tuple(warm_costs), viol,
        tuple(_number(r["dt"]) * (T - 1) for r in results), n_var, n_con, jac_nnz,
        sum(int(_number(r["relaxed"])) for r in results), iterations, build_s, solve_s,
        "; ".join(reasons) or "ok", time.perf_counter() - t0,
    )


def _number(v: object) -> float:
    if not isinstance(v, (int, float)):
        raise TypeError(f"level 3: expected a number, got {type(v).__name__}")
    return float(v)


def _array(v: object) -> FloatArray:
    if not isinstance(v, np.ndarray):
        raise TypeError(f"level 3: expected an array, got {type(v).__name__}")
    return v


@dataclass(frozen=True)
class _Solved:
    """One IPOPT problem's outcome (``_solve``): the optimised paths by block id, and its figures."""

    paths: dict[int, FloatArray]  # id of a block -> (T, n)
    cost: float
    violation: float
    status: str  # IPOPT's return status
    iterations: int
    n_var: int
    n_con: int
    jac_nnz: int
    build_s: float
    solve_s: float


def _solve(model, blocks: list[_Block], idx, w: FloatArray, T: int, max_iter: int) -> _Solved:
    """Solve ``blocks`` as one NLP; a re-solve (at most ROUNDS in all) adds the rows left out that the
    solution violates."""
    n = len(idx)
    build_s = solve_s = 0.0
    iterations, n_var, n_con, jac_nnz, viol, cost, why = 0, 0, 0, 0, 0.0, 0.0, ""
    opt: dict[int, FloatArray] = {}
    x_last = None
    for rnd in range(ROUNDS):
        t1 = time.perf_counter()
        solver, x, g, jac, x0, lbx, ubx, lbg_a, ubg_a = _nlp(model, blocks, idx, w, T, max_iter, x_last is None)
        n_var, n_con = int(x.numel()), int(g.numel())
        jac_nnz = int(jac.sparsity().nnz())
        t2 = time.perf_counter()
        build_s += t2 - t1
        res = solver(x0=x0 if x_last is None else x_last, lbx=lbx, ubx=ubx, lbg=lbg_a, ubg=ubg_a)  # re-solve: from last
        budget.check()  # IPOPT stopped by ``budget.ipopt_stop``: no result
        solve_s += time.perf_counter() - t2
        iterations += int(solver.stats().get("iter_count", 0))
        xs = x_last = np.asarray(res["x"]).reshape(-1)
        gv = np.asarray(res["g"]).reshape(-1)
        viol = float(np.max(np.r_[lbg_a - gv, gv - ubg_a, 0.0]))
        cost, why = float(res["f"]), solver.stats()["return_status"]
        # every row, also those left out, at the solution: add the violated ones and solve again
        added, off = 0, 0
        for b in blocks:
            Zi = np.clip(xs[off:off + n * (T - 2)].reshape(T - 2, n), b.lo, b.hi)  # IPOPT's bound relaxation
            off += n * (T - 2)
            opt[id(b)] = np.vstack([b.Zw[0], Zi, b.Zw[-1]])
            if len(b.lb_all):
                pts = _checkpoints(opt[id(b)])
                vals = np.asarray(b.g_all.map(len(pts))(pts.T)).reshape(len(b.lb_all), -1)
                # kept rows violated at a checkpoint where they were left out: in at every checkpoint
                off_bad = ~b.on & (vals[b.keep] < b.lb - FEAS_TOL)
                if off_bad.any():
                    viol = max(viol, float(np.max((b.lb - vals[b.keep])[off_bad])))
                    b.on[off_bad.any(axis=1)] = True
                    added += int(off_bad.sum())
                low = vals.min(axis=1)
                bad = np.setdiff1d(np.flatnonzero(low < b.lb_all - FEAS_TOL), b.keep)
                if bad.size:  # rows left out altogether: in at every checkpoint
                    viol = max(viol, float(np.max(b.lb_all[bad] - low[bad])))
                    b.keep = np.r_[b.keep, bad]
                    b.lb = np.vstack([b.lb, np.repeat(b.lb_all[bad, None], len(pts), axis=1)])
                    b.on = np.vstack([b.on, np.ones((bad.size, len(pts)), bool)])
                    added += bad.size
        if not added:
            break
        log.debug("level 3 round %d (%d iterations): %d rows left out were violated; solving again", rnd,
                  solver.stats().get("iter_count", 0), added)
    return _Solved(opt, cost, viol, why, iterations, n_var, n_con, jac_nnz, build_s, solve_s)
