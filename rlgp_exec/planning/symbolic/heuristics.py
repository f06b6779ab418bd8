"""Costs and heuristics for :func:`search.best_first` on the mobile-manipulation domain.

* :func:`goal_lower_bound`: an admissible count of the actions the goal still needs (each
  misplaced object needs its own pick, unless held, and place; each drawer goal its own
  take_knob + open/close), so A* with unit costs returns shortest plans first.
* :func:`distance_cost`: the distance-only baseline of R-LGP (RHH-LGP-like): an action costs its
  unit plus the straight-line distance from the previous action's place to its own, with object
  positions tracked through the plan. R-LGP replaces it by the reachability-graph path cost.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from rlgp_exec.planning.actions import PICKS, Kind
from rlgp_exec.planning.symbolic.model import GroundAction, GroundProblem, SymbolicState
from rlgp_exec.planning.symbolic.search import CostFn, Heuristic
from rlgp_exec.scene.geometry import region_box
from rlgp_exec.scene.types import Scene

__all__ = ["distance_cost", "goal_lower_bound", "site_positions"]


def goal_lower_bound(problem: GroundProblem) -> Heuristic:
    """Admissible goal-distance estimate for ``problem`` (unit action costs)."""
    object_goals: dict[str, list[tuple[str, ...]]] = {}
    drawer_goals: dict[str, list[tuple[str, ...]]] = {}
    fills: dict[str, list[tuple[str, ...]]] = {}  # cabinet -> its (in o c) goals
    for g in problem.goal:
        if g[0] in ("on", "in"):
            object_goals.setdefault(g[1], []).append(g)
        if g[0] == "in":
            fills.setdefault(g[2], []).append(g)
        if g[0] in ("open", "closed"):
            drawer_goals.setdefault(g[1], []).append(g)

    def h(state: SymbolicState) -> float:
        held = {a[2] for a in state if a[0] == "holding"}
        knob = {a[2] for a in state if a[0] == "holding-knob"}
        total = 0
        for o, goals in object_goals.items():
            if any(g not in state for g in goals):
                total += 1 if o in held else 2
        for c in set(drawer_goals) | set(fills):
            must_open = ("open", c) not in state and any(g not in state for g in fills.get(c, ()))
            unmet = [g for g in drawer_goals.get(c, ()) if g not in state]
            if must_open:
                total += 1 if c in knob else 2  # (take_knob) open_drawer
                if ("closed", c) in drawer_goals.get(c, ()):
                    total += 2  # take_knob close_drawer after the drop
            elif unmet:
                total += 1 if c in knob else 2
        return float(total)

    return h


def site_positions(scene: Scene) -> dict[str, tuple[float, float]]:
    """Planar position (x, y) of every named thing an action goes to: objects, fixtures, regions."""
    out: dict[str, tuple[float, float]] = {f.name: (f.pose[0], f.pose[1]) for f in scene.fixtures}
    for r in scene.regions:
        T = region_box(scene, r).T
        out[r.name] = (float(T[0, 3]), float(T[1, 3]))
    for o in scene.objects:
        out[o.name] = (o.pose[0], o.pose[1])
    return out


def distance_cost(scene: Scene, per_action: float = 1.0, per_metre: float = 1.0) -> CostFn:
    """The distance-only cost: ``per_action + per_metre * |site(prev) - site(action)|``.

    The site of pick/place/stack/drop is the target (object, support or cabinet), of the drawer
    actions the cabinet; it starts at the robot's base. Objects move with the plan: after a place,
    the object's site is its support's.
    """
    sites = site_positions(scene)
    start = (scene.robot.base[0], scene.robot.base[1])

    def site_of(action: GroundAction, where: dict[str, tuple[float, float]]) -> tuple[float, float]:
        if action.name in PICKS:
            return where.get(action.args[1], start)
        return where.get(action.args[-1], start)

    def cost(prefix: Sequence[GroundAction], action: GroundAction) -> float:
        where = dict(sites)
        here = start
        for a in prefix:
            here = site_of(a, where)
            if a.name in (Kind.PLACE, Kind.STACK, Kind.DROP):
                where[a.args[1]] = where.get(a.args[2], here)
        there = site_of(action, where)
        return per_action + per_metre * math.dist(here, there)

    return cost
