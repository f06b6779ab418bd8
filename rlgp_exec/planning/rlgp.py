"""R-LGP (Algorithm 1): best-first symbolic search guided by the reachability graph's heuristic cost,
then keyframe optimisation and guided paths for each candidate, replanning on geometric failure.

``heuristicCost``: the cost of appending an action is the reachability graph's path cost h from the
hand's previous site to the action's site (object top for a pick; the target's centre, one object
height up, for a place), plus a constant per action; a site the graph cannot reach costs
``UNREACHABLE`` (the sequence is pushed to the back, not dropped). The baseline ("lgp", our stand-in
for RHH-LGP) uses the planar distance between sites instead, from the same search.

Geometric layers available here (``planning.actions``): pick, place (on regions and fixtures), stack
(into a slot region, or onto a movable object's top face, where the plan left it; its site is that
face), and the drawer actions take_knob, open_drawer, close_drawer, drop (their site is the knob, or the
open drawer's interior). Candidates with other actions (pick_from_drawer) are skipped with a reason; the
result says so when nothing else remains.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Sequence

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions import GEOMETRIC_ACTIONS, RELEASES, kind
from rlgp_exec.planning.budget import MEMORY_CAP_BYTES, Budget, BudgetError, using
from rlgp_exec.planning.feasibility import goal_manipulator, unreachable_goal
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.nlp.keyframes import DRAWER_ACTIONS, Action, _target_surface
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.sequence import SequenceGeometry
from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.grounding import ground_scene
from rlgp_exec.planning.symbolic.heuristics import distance_cost, goal_lower_bound
from rlgp_exec.planning.symbolic.model import GroundAction, GroundProblem
from rlgp_exec.planning.symbolic.search import best_first
from rlgp_exec.planning.validate import goal_holds, validate_plan
from rlgp_exec.reach import RGParams
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene

__all__ = ["PLANNERS", "plan_scene"]

log = logging.getLogger(__name__)
PLANNERS = ("rlgp", "lgp")
PER_ACTION = 1.0
UNREACHABLE = 1e3
TIME_BUDGET_S = 90.0  # [s] CPU time (``budget.cpu_clock``) a plan call may spend, every stage included


def to_actions(plan: Sequence[GroundAction]) -> list[Action] | str:
    """The geometric actions of a symbolic plan, or the reason it cannot be realised here."""
    out = []
    for a in plan:
        if a.name not in GEOMETRIC_ACTIONS:
            return f"{a}: the geometric layer handles {list(GEOMETRIC_ACTIONS)} so far"
        if a.name in DRAWER_ACTIONS:
            out.append(Action(a.name, a.args[1]))
        else:
            out.append(Action(a.name, a.args[1], a.args[2] if kind(a.name).target != "none" else None))
    return out


def _site(
    geo: SequenceGeometry, a: GroundAction, where: dict[str, FloatArray], openings: dict[str, float],
    surfaces: dict[str, tuple[FloatArray, tuple[float, float], float]] | None = None,
) -> FloatArray:
    """Where the hand goes for action ``a`` (world frame [m]), objects at ``where``, drawers at ``openings``
    (after the action for open/close: the knob where the drawer ends). ``surfaces``: the place targets'
    ``_target_surface`` by name, filled as they are asked for (the search asks for the same few thousands
    of times)."""
    scene = geo.scene
    if a.name == "pick":
        o = scene.object(a.args[1])
        return where[o.name] + np.array([0.0, 0.0, o.size[2] / 2])
    if a.name in DRAWER_ACTIONS:
        return geo.drawers[a.args[1]].T_world_knob(openings[a.args[1]])[:3, 3]
    if a.name == "drop":
        v, o = geo.drawers[a.args[2]], scene.object(a.args[1])
        T, _ = v.drop_rect(max(openings[a.args[2]], v.travel), max(o.size[:2]) / 2)
        return np.array([T[0, 3], T[1, 3], v.rim_z(openings[a.args[2]]) + o.size[2]])
    if a.name == "stack" and a.args[2] in where:  # on the top face of the object below, where it is now
        below = scene.object(a.args[2])
        return where[below.name] + np.array([0.0, 0.0, below.size[2] / 2 + scene.object(a.args[1]).size[2]])
    surface = surfaces.get(a.args[2]) if surfaces is not None else None
    if surface is None:
        surface = _target_surface(scene, a.args[2])
        if surfaces is not None:
            surfaces[a.args[2]] = surface
    T, _, z = surface
    return np.array([T[0, 3], T[1, 3], z + scene.object(a.args[1]).size[2]])


def rg_cost(geo: SequenceGeometry):
    """heuristicCost from the reachability graph (cached in its solution library)."""
    start = {o.name: np.asarray(o.pose[:3], float) for o in geo.scene.objects}
    surfaces: dict[str, tuple[FloatArray, tuple[float, float], float]] = {}

    def after(a: GroundAction, openings: dict[str, float]) -> None:
        if a.name == "open_drawer":
            openings[a.args[1]] = geo.drawers[a.args[1]].travel
        elif a.name == "close_drawer":
            openings[a.args[1]] = 0.0

    def cost(prefix: Sequence[GroundAction], action: GroundAction) -> float:
        where = dict(start)
        openings = {c: geo.scene.start.opening(c) for c in geo.drawers}
        here = geo.hand_start
        for a in prefix:
            if a.name not in GEOMETRIC_ACTIONS:
                return UNREACHABLE
            after(a, openings)
            here = _site(geo, a, where, openings, surfaces)
            if a.name in RELEASES:
                where[a.args[1]] = here - np.array([0.0, 0.0, geo.scene.object(a.args[1]).size[2] / 2])
        if action.name not in GEOMETRIC_ACTIONS:
            return UNREACHABLE
        after(action, openings)
        h = geo.heuristic_cost(here, _site(geo, action, where, openings, surfaces))
        return PER_ACTION + (h if math.isfinite(h) else UNREACHABLE)

    return cost


def plan_scene(
    scene: Scene,
    planner: str = "rlgp",
    max_candidates: int = 8,
    max_expansions: int = 20_000,
    params: RGParams | None = None,
    seed: int = 0,
    time_budget_s: float = TIME_BUDGET_S,
    memory: PlannerMemory | None = None,
    memory_cap_bytes: int = MEMORY_CAP_BYTES,
) -> Plan:
    """Plan the scene's goal; the returned Plan is validated by replay (``success``) or says why not.
    The call spends at most ``time_budget_s`` [s] of CPU time and grows the process by at most
    ``memory_cap_bytes`` (``planning.budget``: checked inside every stage; once spent, the Plan fails with a
    reason "budget: ..." naming the stage and candidate). ``memory`` keeps the reachability graph, and what
    this call teaches it, for the next call."""
    if planner not in PLANNERS:
        raise RlgpError(f"unknown planner {planner!r}; valid: {list(PLANNERS)}")
    t0 = time.perf_counter()
    budget = Budget(time_budget_s, memory_cap_bytes)
    try:
        problem = ground_scene(scene, manipulators=[goal_manipulator(scene)])
    except SymbolicError as e:  # before any geometry: a bad goal is named at once
        dt = time.perf_counter() - t0
        return Plan(False, planner, (), np.zeros((0, 0)), (), dt, 0, 0, None, f"invalid goal: {e}")
    poses = {o.name: o.T for o in scene.objects}
    openings = dict(scene.start.openings)
    held = scene.start.held  # an object in the hand is not where any goal wants it
    if all(held not in lit.args and goal_holds(scene, lit, poses, openings)[0] for lit in scene.goal.literals):
        already = validate_plan(scene, [])
        if already.ok:
            dt = time.perf_counter() - t0
            return Plan(True, planner, (), np.zeros((0, 0)), (), dt, 0, 0, already, "the goal already holds")
    with using(budget):
        try:
            geo = SequenceGeometry(scene, params, seed, memory)
        except BudgetError as e:
            log.info("%s: %s", planner, e)
            return Plan(False, planner, (), np.zeros((0, 0)), (), time.perf_counter() - t0, 0, 0, None, str(e))
        try:
            return _candidates(geo, problem, planner, max_candidates, max_expansions, t0, budget)
        finally:
            geo.close()


def _candidates(
    geo: SequenceGeometry, problem: GroundProblem, planner: str, max_candidates: int, max_expansions: int,
    t0: float, budget: Budget,
) -> Plan:
    """``plan_scene``'s loop over the symbolic search's candidates."""
    scene = geo.scene
    cost = rg_cost(geo) if planner == "rlgp" else distance_cost(scene)
    search = best_first(problem, cost, max_expansions, heuristic=goal_lower_bound(problem))
    reasons: list[str] = []

    def failed(reason: str) -> Plan:
        return Plan(
            False, planner, (), np.zeros((0, geo.model.nq)), (), time.perf_counter() - t0, geo.n_nlp,
            search.stats.expanded, None, reason,
        )

    try:
        with budget.at("symbolic search", "candidate 0"):
            for k, cand in enumerate(search):
                if k >= max_candidates:
                    break
                budget.check()
                actions = to_actions(cand.actions)
                if isinstance(actions, str):
                    reasons.append(actions)
                    continue
                with budget.at("geometry", f"candidate {k}"):
                    result = geo.plan_actions(actions, planner, search.stats.expanded, t_start=t0)
                log.info("%s candidate %d %s: %s", planner, k, cand, result.reason)
                if result.success:
                    return result
                reasons.append(f"{cand}: {result.reason}")
                if len(reasons) == 1:  # the first geometric failure: is the goal reachable at all?
                    with budget.at("reachability of the goal", f"candidate {k}"):
                        infeasible = unreachable_goal(geo, problem)
                    if infeasible is not None:
                        return failed(infeasible)
                budget.scope = f"candidate {k + 1}"  # the search's next expansions are for the next one
    except BudgetError as e:
        geo.reset()  # a stage cut short leaves no drawer, object or carried box in the shared graph's world
        first = f"; first: {reasons[0]}" if reasons else ""
        log.info("%s: %s after %d candidates", planner, e, len(reasons))
        return failed(f"{e}{first}")
    if search.stats.exhausted and not reasons:
        return failed("infeasible: no symbolic plan reaches the goal")
    why = "; ".join(reasons[-3:]) or "no symbolic plan within the search budget"
    return failed(f"no valid plan after {len(reasons)} candidates: {why}")
