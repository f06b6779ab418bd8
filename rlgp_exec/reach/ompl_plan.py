"""OMPL for configuration-space segments the reachability graph cannot certify (and for comparison).

Plans over the graph's planning joints (base x, y, yaw and the arm; every other joint fixed) with
RRTConnect (or PRM) on the same PyBullet validity check the graph uses. OMPL's own motion check is
sampled, so every segment of the simplified result is re-checked with the exact edge check of
:class:`~rlgp_exec.reach.checker.WorldChecker` before the path is returned. OMPL's states keep three
times the graph's clearance; an end closer than that (a grasp's approach next to a cabinet) is
replaced by a configuration nearby that has it and that the end reaches by a straight motion passing
the exact check (that motion is part of the returned path).
"""

from __future__ import annotations

import itertools
import logging
import math
from collections.abc import Callable, Sequence

import numpy as np

from rlgp_exec.planning import budget
from rlgp_exec.reach.checker import CLEARANCE, WorldChecker
from rlgp_exec.robot.model import FloatArray, RobotModel

__all__ = ["OMPL_PLANNERS", "drive_base", "drive_postures", "plan_ompl"]

log = logging.getLogger(__name__)
OMPL_PLANNERS = ("RRTConnect", "PRM")
OMPL_CLEARANCE = 3 * CLEARANCE  # [m] required of OMPL's states
REDUCE_STEPS = 20  # OMPL vertex-reduction attempts on a found path
NUDGE_SIGMAS = (0.01, 0.02, 0.04)  # [m or rad] an end OMPL refuses is moved by Gaussian steps this wide
NUDGE_TRIES = 8  # samples per sigma


_SEEDED: list[bool] = []


def _seed_once(seed: int = 1) -> None:
    """OMPL's random generator, seeded once per process (it can only be seeded before first use), so
    that a planning run is repeatable when it is not cut short by its time limit."""
    if not _SEEDED:
        # local: OMPL's bindings load only for a plan that falls back to OMPL
        from ompl import util as ou

        ou.setLogLevel(ou.LogLevel.LOG_ERROR)  # OMPL writes to stdout itself; our own log says what matters
        ou.RNG.setSeed(seed)
        _SEEDED.append(True)


def plan_ompl(
    checker: WorldChecker,
    plan_idx: FloatArray,
    q1: FloatArray,
    q2: FloatArray,
    lo_xy: FloatArray,
    hi_xy: FloatArray,
    planner: str = "RRTConnect",
    timeout: float = 1.0,
) -> FloatArray | None:
    """A collision-free path (n, nq) from q1 to q2, or None (timeout, or no certifiable path). ``plan_idx``:
    the joints planned (with any other that differs between the ends); ``lo_xy``/``hi_xy``: the base's
    x, y box [m] when it is planned (joints 0 and 1)."""
    # local: OMPL's bindings load only for a plan that falls back to OMPL
    from ompl import base as ob
    from ompl import geometric as og

    _seed_once()

    if planner not in OMPL_PLANNERS:
        raise ValueError(f"unknown OMPL planner {planner!r}; valid: {list(OMPL_PLANNERS)}")
    model = checker.model
    q2 = q1 + model.limits.difference(q2, q1)  # unwrapped next to q1
    # the graph's joints, and any other that differs between the ends (a lift raised for an approach)
    differs = np.flatnonzero(np.abs(q2 - q1) > 1e-9)
    idx = np.union1d(np.asarray(plan_idx, dtype=int), differs).astype(int)
    lo, hi = model.limits.lower[idx].copy(), model.limits.upper[idx].copy()
    for k, i in enumerate(idx):
        if not (np.isfinite(lo[k]) and np.isfinite(hi[k])):  # continuous: one turn around the start
            lo[k], hi[k] = min(q1[i], q2[i]) - math.pi, max(q1[i], q2[i]) + math.pi
    if idx.size >= 2 and idx[0] == 0 and idx[1] == 1:  # the base's x and y planned: the caller's box
        lo[:2] = np.minimum(lo_xy, np.minimum(q1[:2], q2[:2]))
        hi[:2] = np.maximum(hi_xy, np.maximum(q1[:2], q2[:2]))
    # an end a hair outside a joint limit (an optimiser's bound relaxation) must not void the query
    lo, hi = np.minimum(lo, np.minimum(q1[idx], q2[idx])), np.maximum(hi, np.maximum(q1[idx], q2[idx]))
    n = idx.size
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for k in range(n):
        bounds.setLow(k, float(lo[k]))
        bounds.setHigh(k, float(hi[k]))
    space.setBounds(bounds)
    ss = og.SimpleSetup(space)
    base_q = q1.copy()

    def full(s) -> FloatArray:
        q = base_q.copy()
        q[idx] = [s[k] for k in range(n)]
        return q

    def valid(s) -> bool:
        # three times the graph's clearance: OMPL's sampled motions then pass the exact edge check
        q = full(s)
        return checker.distance(q, upto=OMPL_CLEARANCE) >= OMPL_CLEARANCE and not checker.self_collision(q)

    s1, s2 = _nudged(checker, q1, idx, lo, hi), _nudged(checker, q2, idx, lo, hi)
    if s1 is None or s2 is None:  # OMPL would spend its whole timeout on it
        log.info(
            "OMPL: the %s is not valid (within %.3f m of a fixture, or self-colliding), nor any nearby",
            "start" if s1 is None else "goal",
            OMPL_CLEARANCE,
        )
        return None
    ss.setStateValidityChecker(valid)
    start, goal = space.allocState(), space.allocState()
    for k, i in enumerate(idx):
        start[k], goal[k] = float(s1[i]), float(s2[i])
    ss.setStartAndGoalStates(start, goal)
    si = ss.getSpaceInformation()
    si.setStateValidityCheckingResolution(0.001)  # a fraction of the space's extent: ~1 cm here
    ss.setPlanner(og.RRTConnect(si) if planner == "RRTConnect" else og.PRM(si))
    for attempt in range(3):  # OMPL's sampled motion check can cut a corner the exact check refuses
        if attempt:
            ss.clear()
        budget.check()  # not inside ``valid``: OMPL calls it, and an exception must not cross into OMPL
        if not ss.solve(max(0.01, min(timeout / 3, budget.left()))) or not ss.haveExactSolutionPath():
            continue
        sol = ss.getSolutionPath()
        # a bounded vertex reduction only (OMPL's full simplify can take seconds with this validity
        # check); the caller shortcuts the result with the exact edge check
        og.PathSimplifier(si).reduceVertices(sol, REDUCE_STEPS)
        states = [full(s) for s in sol.getStates()]
        states = ([q1] if s1 is not q1 else []) + states + ([q2] if s2 is not q2 else [])
        path = model.limits.wrap(np.array(states))
        if not any(checker.edge_collides(a, b) for a, b in itertools.pairwise(path)):
            return path
        log.info("OMPL %s path failed the exact edge check (attempt %d)", planner, attempt + 1)
    log.info("OMPL %s found no certified path in %.1f s", planner, timeout)
    return None


def drive_postures(
    model: RobotModel, q1: FloatArray, q2: FloatArray, empty_hand: bool
) -> tuple[FloatArray, list[FloatArray]]:
    """(rigid joint indices, postures over them) for ``drive_base``, in the order to try: q2's own;
    folded (the home posture, torso up; empty hand only: the checks do not cover a held object
    against the robot's body); q1's with the lift up."""
    arm = np.array(model.group(model.manipulator().group), dtype=int)
    torso = [model.index(n) for n in ("torso_lift_joint",) if n in model.joint_names]
    rigid = np.array(sorted({*arm.tolist(), *torso}), dtype=int)
    postures = [q2[rigid]]
    if empty_hand:
        home = model.home()[rigid]
        for i, j in enumerate(rigid):
            if j not in arm:  # the torso up
                home[i] = model.limits.upper[j] - 0.01
        postures.append(home)
    up = q1[rigid].copy()
    for i, j in enumerate(rigid):
        if model.joint_names[j].endswith("lift_joint"):
            up[i] = max(up[i], model.limits.upper[j] - 0.01)
    postures.append(up)
    return rigid, postures


def drive_base(
    checker: WorldChecker,
    q1: FloatArray,
    q2: FloatArray,
    rigid: FloatArray,
    postures: Sequence[FloatArray],
    lo_xy: FloatArray,
    hi_xy: FloatArray,
    timeout: float,
    free: Callable[[FloatArray, FloatArray | None], bool] | None = None,
) -> FloatArray | None:
    """A path (n, nq) from q1 to q2 that moves the base with the joints ``rigid`` held in one posture:
    q1 -> q1's base in the posture -> the base to q2's (straight if that motion is free, else OMPL on
    the base's x, y, yaw alone) -> q2. ``postures`` (each (len(rigid),)) are tried in order; ``free(q,
    None)`` says q is collision-free and ``free(q, q_to)`` the straight motion (default: the checker,
    exactly). None if every posture fails (``timeout`` [s] per OMPL query)."""
    if free is None:

        def free(q: FloatArray, q_to: FloatArray | None = None) -> bool:
            return not (checker(q) if q_to is None else checker.edge_collides(q, q_to))

    base = np.array(checker.model.group("base"))
    for posture in postures:
        p1, p2 = q1.copy(), q2.copy()
        p1[rigid], p2[rigid] = posture, posture
        if not all(free(q, None) for q in (p1, p2)):
            continue
        if not (free(q1, p1) and free(p2, q2)):
            continue
        if free(p1, p2):
            return np.array([q1, p1, p2, q2])
        path = plan_ompl(checker, base, p1, p2, lo_xy, hi_xy, timeout=timeout)
        if path is not None:
            return np.vstack([q1[None], path, q2[None]])
    return None


def _nudged(checker: WorldChecker, q: FloatArray, idx: FloatArray, lo: FloatArray, hi: FloatArray) -> FloatArray | None:
    """q itself if OMPL accepts it (``valid_q``), else the first of Gaussian samples round q in the
    joints ``idx`` (inside [lo, hi], widening NUDGE_SIGMAS, seeded: repeatable) that OMPL accepts and
    that q reaches by a straight motion passing the exact edge check; None if none does."""
    if valid_q(checker, q):
        return q
    rng = np.random.default_rng(0)
    for sigma in NUDGE_SIGMAS:
        for _ in range(NUDGE_TRIES):
            z = q.copy()
            z[idx] = np.clip(q[idx] + rng.normal(0.0, sigma, len(idx)), lo, hi)
            if valid_q(checker, z) and not checker.edge_collides(q, z):
                return z
    return None


def valid_q(checker: WorldChecker, q: FloatArray) -> bool:
    """OMPL's validity of a whole configuration: OMPL_CLEARANCE from the fixtures, no self-collision."""
    return checker.distance(q, upto=OMPL_CLEARANCE) >= OMPL_CLEARANCE and not checker.self_collision(q)
