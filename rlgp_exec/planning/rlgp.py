"""R-LGP (Algorithm 1): best-first symbolic search guided by the reachability graph's heuristic cost,
then keyframe optimisation and guided paths for each candidate, replanning on geometric failure.

``heuristicCost`` (:class:`RGCost`): the cost of appending an action is the reachability graph's path
cost from the hand's previous site to the action's site (object top for a pick; the target's centre, one
object height up, for a place), plus a constant per action; a site the graph cannot reach costs
``UNREACHABLE`` (the sequence is pushed to the back, not dropped). The search is weighted A* with a
heuristic in the same units (the actions still needed, each misplaced object's carry to its goal and its
cheapest approach), over the problem without detours (``symbolic.relevance``), so it grows with the
number of objects instead of their orderings. Towers and Hanoi (``symbolic.stacking``): an object counts as
misplaced until its whole chain of supports is in place (a block goes down before the one on it; one with
something on it is cleared first), a tower block's goal site is where the finished tower has it, and the
search never picks up an object in place again nor sets one down elsewhere while its goal support is ready.
A candidate whose keyframes fail in a leading chunk
(``nlp.keyframe_chunks``) forbids that prefix to the candidates after it. The baseline ("lgp", our
stand-in for RHH-LGP) uses the planar distance between sites instead, from the same search.

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
from typing import NamedTuple

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions import DRAWER_ACTIONS, GEOMETRIC_ACTIONS, RELEASES, Kind, kind
from rlgp_exec.planning.budget import MEMORY_CAP_BYTES, Budget, BudgetError, using
from rlgp_exec.planning.capabilities import refuse
from rlgp_exec.planning.feasibility import goal_manipulator, unreachable_goal
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.nlp.action import Action, target_surface
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.sequence import SequenceGeometry
from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.grounding import ground_scene
from rlgp_exec.planning.symbolic.heuristics import goal_lower_bound
from rlgp_exec.planning.symbolic.model import GroundAction, GroundProblem, SymbolicState
from rlgp_exec.planning.symbolic.relevance import without_detours
from rlgp_exec.planning.symbolic.search import best_first
from rlgp_exec.planning.symbolic.stacking import Stacking
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
SEARCH_WEIGHT = 1.25  # weighted A*: a first candidate within 1.25 times the cheapest, in far fewer expansions


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
    ``target_surface`` by name, filled as they are asked for (the search asks for the same few thousands
    of times)."""
    scene = geo.scene
    if a.name == Kind.PICK:
        o = scene.object(a.args[1])
        return where[o.name] + np.array([0.0, 0.0, o.size[2] / 2])
    if a.name in DRAWER_ACTIONS:
        return geo.drawers[a.args[1]].T_world_knob(openings[a.args[1]])[:3, 3]
    if a.name == Kind.DROP:
        v, o = geo.drawers[a.args[2]], scene.object(a.args[1])
        T, _ = v.drop_rect(max(openings[a.args[2]], v.travel), max(o.size[:2]) / 2)
        return np.array([T[0, 3], T[1, 3], v.rim_z(openings[a.args[2]]) + o.size[2]])
    if a.name == Kind.STACK and a.args[2] in where:  # on the top face of the object below, where it is now
        below = scene.object(a.args[2])
        return where[below.name] + np.array([0.0, 0.0, below.size[2] / 2 + scene.object(a.args[1]).size[2]])
    surface = surfaces.get(a.args[2]) if surfaces is not None else None
    if surface is None:
        surface = target_surface(scene, a.args[2])
        if surfaces is not None:
            surfaces[a.args[2]] = surface
    T, _, z = surface
    return np.array([T[0, 3], T[1, 3], z + scene.object(a.args[1]).size[2]])


def _after(geo: SequenceGeometry, a: GroundAction, openings: dict[str, float]) -> dict[str, float]:
    """The drawer openings after action ``a`` (a new dict when a drawer moves, else ``openings``)."""
    if a.name == Kind.OPEN_DRAWER:
        return {**openings, a.args[1]: geo.drawers[a.args[1]].travel}
    if a.name == Kind.CLOSE_DRAWER:
        return {**openings, a.args[1]: 0.0}
    return openings


def _planar_distance(x1: FloatArray, x2: FloatArray) -> float:
    """The distance-only baseline's cost between two sites [m]: straight-line, in the plane."""
    return float(math.hypot(x2[0] - x1[0], x2[1] - x1[1]))


class _Where(NamedTuple):
    """Where a plan prefix leaves things: the hand's site [m], objects' centres [m], drawer openings [m]."""

    here: FloatArray  # (3,)
    objects: dict[str, FloatArray]  # name -> (3,), world frame
    openings: dict[str, float]


class RGCost:
    """heuristicCost as a :class:`PathCost`: an action costs ``PER_ACTION`` plus the reachability graph's
    path cost from the hand's previous site to its own (``UNREACHABLE`` if the graph has none); objects and
    drawers move with the plan. ``remaining`` adds to ``PER_ACTION`` times the actions the goal still needs
    (``goal_lower_bound``) the graph cost of carrying each misplaced object from where it is to its goal's
    site, and for each one the cheapest approach to it (from the hand, or from another misplaced object's
    goal, where the hand is after putting that one down): a bound in the same units as the cost (blockers'
    and drawers' sites left out), so the search orders by metres instead of exploring every ordering with
    the same count of actions. With stacking goals (``symbolic.stacking``) the objects not in place (a goal
    that holds on a support not yet in place, what rests on one, what stands on a goal region) add their
    two actions, carry and approach too, and a tower block's goal site is the finished tower's. ``estimate`` is
    ``geo.heuristic_cost`` for R-LGP; the distance-only baseline passes the straight-line distance."""

    def __init__(self, geo: SequenceGeometry, problem: GroundProblem, estimate=None) -> None:
        self.geo = geo
        self.scene = geo.scene
        self.estimate = estimate or geo.heuristic_cost
        self.count = goal_lower_bound(problem)
        self.surfaces: dict[str, tuple[FloatArray, tuple[float, float], float]] = {}
        self._costs: dict[bytes, float] = {}
        movable = {n for n, t in problem.objects if t == "movable"}
        self.goals = [(g, g[1], g[2]) for g in problem.goal if g[0] in ("on", "in")]
        self.kind = {
            s: (Kind.DROP if g[0] == "in" else Kind.STACK if s in movable else Kind.PLACE) for g, _, s in self.goals
        }
        self.arm = next((n for n, t in problem.objects if t == "manipulator"), "arm")
        self.stacking = Stacking(problem, {r.name for r in self.scene.regions})
        self._final = self._final_sites()

    def _cost(self, x1: FloatArray, x2: FloatArray) -> float:
        key = x1.tobytes() + x2.tobytes()
        h = self._costs.get(key)
        if h is None:
            h = self.estimate(x1, x2)
            h = self._costs[key] = h if math.isfinite(h) else UNREACHABLE
        return h

    def start(self) -> _Where:
        scene = self.scene
        return _Where(
            np.asarray(self.geo.hand_start, float),
            {o.name: np.asarray(o.pose[:3], float) for o in scene.objects},
            {c: scene.start.opening(c) for c in self.geo.drawers},
        )

    def step(self, context: _Where, action: GroundAction) -> tuple[float, _Where]:
        if action.name not in GEOMETRIC_ACTIONS:
            return UNREACHABLE, context
        openings = _after(self.geo, action, context.openings)
        there = _site(self.geo, action, context.objects, openings, self.surfaces)
        objects = context.objects
        if action.name in RELEASES:
            o = action.args[1]
            objects = {**objects, o: there - np.array([0.0, 0.0, self.scene.object(o).size[2] / 2])}
        return PER_ACTION + self._cost(context.here, there), _Where(there, objects, openings)

    def _goal_site(self, o: str, s: str, context: _Where) -> FloatArray:
        kind = self.kind[s]  # a stack's site is on its support object, wherever the plan has left it
        openings = context.openings
        if kind == Kind.DROP:
            openings = {**openings, s: self.geo.drawers[s].travel}
        final = self._final.get(o)
        if final is not None:  # a tower's block: where the tower will have it, not on its support's site now
            return final
        return _site(self.geo, GroundAction(kind, (self.arm, o, s)), context.objects, openings, self.surfaces)

    def _final_sites(self) -> dict[str, FloatArray]:
        """The hand's site [m] at the put-down of each object whose goal stacks it onto another object, when
        the goal's chain of supports ends on a region or fixture: that target's centre, the chain's heights
        up (the top of the object there)."""
        goal_on = self.stacking.goal_on
        out: dict[str, FloatArray] = {}
        for o, s in goal_on.items():
            if s not in self.stacking.movable:
                continue
            chain, x = [o], s
            while x in self.stacking.movable and x in goal_on and x not in chain:
                chain.append(x)
                x = goal_on[x]
            if x in self.stacking.movable:  # the chain ends on an object without a goal, or loops
                continue
            T, _, z = self.surfaces.get(x) or self.surfaces.setdefault(x, target_surface(self.scene, x))
            height = sum(self.scene.object(m).size[2] for m in chain)
            out[o] = np.array([T[0, 3], T[1, 3], z + height])
        return out

    def remaining(self, state: SymbolicState, context: _Where) -> float:
        held = {a[2] for a in state if a[0] == "holding"}
        carry, loose = 0.0, []
        ends = [context.here]  # where the hand can come from to each pick: here, or another object's goal
        unmet = set(held)
        count = PER_ACTION * self.count(state)

        def top_of(o: str) -> FloatArray:
            return context.objects[o] + np.array([0.0, 0.0, self.scene.object(o).size[2] / 2])

        for g, o, s in self.goals:
            if g in state:
                continue
            unmet.add(o)
            goal_site = self._goal_site(o, s, context)
            if o in held:
                carry += self._cost(context.here, goal_site)
            else:
                top = top_of(o)
                carry += self._cost(top, goal_site)
                loose.append((top, len(ends)))
            ends.append(goal_site)
        # objects whose goal holds on a support not yet in place, and what rests on them: moved again
        for o in self.stacking.unfinished(state, unmet):
            count += 2 * PER_ACTION
            top = top_of(o)
            support = self.stacking.goal_on.get(o)
            if support is None:  # cleared off to anywhere: its approach only
                loose.append((top, -1))
                continue
            goal_site = self._goal_site(o, support, context)
            carry += self._cost(top, goal_site)
            loose.append((top, len(ends)))
            ends.append(goal_site)
        approach = sum(min(self._cost(e, top) for k, e in enumerate(ends) if k != own) for top, own in loose)
        return count + carry + approach


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
    refuse(scene, planner)  # TaskRefusedError before any search: what the planner or the robot cannot do
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
    model = RGCost(geo, problem, None if planner == "rlgp" else _planar_distance)
    prune = model.stacking.prune if model.stacking.active else None
    search = best_first(without_detours(problem), max_expansions=max_expansions, weight=SEARCH_WEIGHT, model=model,
                        prune=prune)
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
                log.info("%s candidate %d: %d actions after %d expansions (symbolic cost %.1f); solving its geometry",
                         planner, k, len(actions), search.stats.expanded, cand.cost)
                with budget.at("geometry", f"candidate {k}"):
                    result = geo.plan_actions(actions, planner, search.stats.expanded, t_start=t0)
                log.info("%s candidate %d %s: %s", planner, k, cand, result.reason)
                if result.success:
                    return result
                reasons.append(f"{cand}: {result.reason}")
                if result.doomed:  # the next candidates must differ within the failing prefix
                    search.forbid(cand.actions[: result.doomed])
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
