"""The symbolic layer at scale: detour pruning loses no plan, a path-dependent cost (``PathCost``) drives the
same search, weighted A* stays within its bound, and R-LGP's metric heuristic finds sorting plans for ten
objects in few expansions (the count of expansions is the property; the time is the bench's)."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from rlgp_exec.planning.feasibility import goal_manipulator
from rlgp_exec.planning.symbolic import best_first, goal_lower_bound, ground_scene
from rlgp_exec.planning.symbolic.heuristics import site_positions
from rlgp_exec.planning.symbolic.relevance import PUT_DOWN, without_detours
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.generate import sorting_scene

SCENES = sorted(Path(__file__).resolve().parents[1].joinpath("sim", "scenes").glob("*.toml"))


class PlanarDistance:
    """A test PathCost: 1 per action plus the planar distance between the supports' centres."""

    def __init__(self, scene, problem):
        self.sites = site_positions(scene)
        self.start_xy = (scene.robot.base[0], scene.robot.base[1])
        self.count = goal_lower_bound(problem)

    def _site(self, where, action):
        return where[action.args[1]] if action.name == "pick" else where[action.args[-1]]

    def start(self):
        return (self.start_xy, dict(self.sites))

    def step(self, context, action):
        here, where = context
        there = self._site(where, action)
        if action.name in PUT_DOWN:
            where = {**where, action.args[1]: there}
        return 1.0 + math.dist(here, there), (there, where)

    def remaining(self, state, context):
        return self.count(state)  # admissible: each action costs at least 1


@pytest.mark.parametrize("path", SCENES, ids=[p.stem for p in SCENES])
def test_detour_pruning_keeps_the_shortest_plan(path):
    scene = load_scene(path)
    full = ground_scene(scene)
    pruned = without_detours(full)
    plan_full = next(best_first(full, max_expansions=50_000, heuristic=goal_lower_bound(full)))
    plan = next(best_first(pruned, max_expansions=50_000, heuristic=goal_lower_bound(pruned)))
    assert len(plan.actions) == len(plan_full.actions)
    assert full.reaches_goal(plan.actions)  # a plan of the pruned problem is one of the problem's


def test_detour_pruning_removes_exactly_the_detours():
    problem = ground_scene(sorting_scene("pr2", 4, 0))
    pruned = without_detours(problem)
    goal = {g[1]: g[2] for g in problem.goal}
    removed = set(problem.operators) - set(pruned.operators)
    assert removed
    for op in removed:
        a = op.action
        away = a.name in PUT_DOWN and a.args[2] != goal[a.args[1]]
        assert away or (a.name == "pick" and a.args[2] == goal[a.args[1]])
    for op in pruned.operators:
        a = op.action
        if a.name in PUT_DOWN:
            assert a.args[2] == goal[a.args[1]]


def test_a_path_cost_drives_the_search_and_weighting_stays_within_its_bound():
    scene = sorting_scene("pr2", 4, 1)
    problem = without_detours(ground_scene(scene, manipulators=[goal_manipulator(scene)]))
    model = PlanarDistance(scene, problem)
    optimal = next(best_first(problem, max_expansions=200_000, model=model))
    assert problem.reaches_goal(optimal.actions)
    context, cost = model.start(), 0.0
    for a in optimal.actions:  # the plan's cost is the sum of its steps along its own path
        step, context = model.step(context, a)
        cost += step
    assert cost == pytest.approx(optimal.cost)
    for weight in (1.5, 3.0):
        it = best_first(problem, max_expansions=200_000, model=model, weight=weight)
        plan = next(it)
        assert problem.reaches_goal(plan.actions) and plan.cost <= weight * optimal.cost + 1e-9


@pytest.fixture(scope="module")
def sorting10():
    from rlgp_exec.planning.sequence import SequenceGeometry

    scene = sorting_scene("pr2", 10, 0)
    geo = SequenceGeometry(scene, None, 0, None)
    yield scene, geo
    geo.close()


def test_rlgp_metric_heuristic_plans_ten_objects_in_few_expansions(sorting10):
    from rlgp_exec.planning.rlgp import SEARCH_WEIGHT, RGCost

    scene, geo = sorting10
    problem = without_detours(ground_scene(scene, manipulators=[goal_manipulator(scene)]))
    model = RGCost(geo, problem)
    it = best_first(problem, max_expansions=2_000, weight=SEARCH_WEIGHT, model=model)
    plan = next(it)
    assert problem.reaches_goal(plan.actions) and len(plan.actions) == 20
    assert it.stats.expanded < 1_000  # the unit-count heuristic did not find one in 20,000
    h0 = model.remaining(problem.init, model.start())
    assert 0.8 * plan.cost <= h0 <= plan.cost  # a tight bound, never above a detour-free plan's cost
    unit = best_first(problem, max_expansions=2_000, heuristic=goal_lower_bound(problem), cost_fn=_metres(model))
    with pytest.raises(StopIteration):
        next(unit)
    assert unit.stats.budget_hit


def _metres(model):
    """The same costs as a prefix cost function (no path context), for the unit-heuristic comparison."""

    def cost(prefix, action):
        context = model.start()
        for a in prefix:
            _, context = model.step(context, a)
        return model.step(context, action)[0]

    return cost
