"""R-LGP on the shipped stacking scenes: the six-cube tower and the Tower of Hanoi on the PR2 plan and
validate by replay; the stacking order in the symbolic search (what must go down first, what must be
cleared); 5 cm cubes and 3 cm discs picked from the table (the fingers, not the tool sphere, against the
surface under them); a block picked again where the plan put it; the world model's stacks."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from rlgp_exec.executive.world import carried_along, stacks, update_scene
from rlgp_exec.planning.actions import parse_text
from rlgp_exec.planning.feasibility import goal_manipulator, unreachable_goal
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.keyframes import pinned_conflict
from rlgp_exec.planning.rlgp import SEARCH_WEIGHT, RGCost, _planar_distance, plan_scene
from rlgp_exec.planning.symbolic.grounding import ground_scene
from rlgp_exec.planning.symbolic.relevance import without_detours
from rlgp_exec.planning.symbolic.search import best_first
from rlgp_exec.planning.symbolic.stacking import Stacking, supports
from rlgp_exec.planning.validate import ON_TOLERANCE
from rlgp_exec.robot import load_robot
from rlgp_exec.scene.loader import load_scene

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"


def scene(name: str):
    return load_scene(SCENES / f"{name}.toml")


def words(plan) -> list[tuple[str, ...]]:
    return [(w.name, w.obj, *([w.target] if w.target else [])) for w in map(parse_text, plan.actions)]


def assert_rests_on(sc, poses, upper: str, lower: str) -> None:
    lo, up = sc.object(lower), sc.object(upper)
    gap = (poses[upper][2, 3] - up.size[2] / 2) - (poses[lower][2, 3] + lo.size[2] / 2)
    assert abs(gap) <= ON_TOLERANCE, (upper, lower, gap)
    d = np.linalg.solve(poses[lower], poses[upper][:, 3])  # the upper's centre in the lower's frame
    assert abs(d[0]) <= lo.size[0] / 2 and abs(d[1]) <= lo.size[1] / 2, (upper, lower, d[:2])


@pytest.fixture(scope="module")
def tower_plan():
    return plan_scene(scene("tower_pr2"), "rlgp")


@pytest.fixture(scope="module")
def hanoi_plan():
    return plan_scene(scene("hanoi_pr2"), "rlgp")


def test_six_cube_tower_plans_and_validates(tower_plan):
    assert tower_plan.success, tower_plan.reason
    assert tower_plan.validation is not None and tower_plan.validation.ok
    sc = scene("tower_pr2")
    blocks = [f"b{k}" for k in range(1, 7)]
    for lower, upper in itertools.pairwise(blocks):
        assert_rests_on(sc, tower_plan.validation.final_poses, upper, lower)
    # each block goes down before the one on it, and none is set down anywhere but its goal
    assert [w[1] for w in words(tower_plan) if w[0] in ("place", "stack")] == blocks


def test_hanoi_plans_and_validates(hanoi_plan):
    assert hanoi_plan.success, hanoi_plan.reason
    sc = scene("hanoi_pr2")
    poses = hanoi_plan.validation.final_poses
    assert_rests_on(sc, poses, "d_mid", "d_large")
    assert_rests_on(sc, poses, "d_small", "d_mid")
    # the domain's rule: never a larger disc on a smaller one, at any step
    size = {o.name: o.size[0] for o in sc.objects}
    for w in words(hanoi_plan):
        if w[0] == "stack" and w[2] in size:
            assert size[w[1]] <= size[w[2]], w


def test_the_search_builds_the_tower_bottom_up_without_detours():
    """The search's metric model (here with the baseline's planar distances: no graph needed) orders the
    six-cube tower bottom up at once, instead of the thousands of expansions of temporary placements."""
    sc = scene("tower_pr2")
    problem = ground_scene(sc, manipulators=["right_arm"])
    geo = SimpleNamespace(scene=sc, hand_start=np.array([0.0, -0.4, 0.95]), drawers={})
    model = RGCost(geo, problem, _planar_distance)  # type: ignore[arg-type]
    search = best_first(without_detours(problem), max_expansions=2000, weight=SEARCH_WEIGHT, model=model,
                        prune=model.stacking.prune)
    first = next(search)
    puts = [a.args[1] for a in first.actions if a.name in ("place", "stack")]
    assert puts == [f"b{k}" for k in range(1, 7)]
    assert len(first.actions) == 12
    assert search.stats.expanded < 200, search.stats


def test_stacking_counts_what_is_not_in_place():
    problem = ground_scene(scene("tower_pr2"), manipulators=["right_arm"])
    st = Stacking(problem)
    assert st.active
    init = set(problem.init)
    # b2 on b1 while b1 still stands on the table: b2's goal literal holds, yet both must move again
    state = frozenset((init - {("on", "b2", "table"), ("clear", "b1")}) | {("on", "b2", "b1")})
    placed = st.in_place(supports(state))
    assert not placed["b2"] and not placed["b1"]
    unmet_goals = {"b1", "b3", "b4", "b5", "b6"}  # what the goal count has already
    assert st.unfinished(state, unmet_goals) == ["b2"]
    # b1 on the goal region, b2 on it: both in place, and picking b2 up again is pruned
    done = frozenset((init - {("on", "b1", "table"), ("on", "b2", "table"), ("clear", "goal_region"),
                              ("clear", "b1")}) | {("on", "b1", "goal_region"), ("on", "b2", "b1")})
    assert st.in_place(supports(done))["b2"]
    picked = next(s for a, s in problem.successors(done) if a.name == "pick" and a.args[1] == "b2")
    pick = next(a for a, s in problem.successors(done) if a.name == "pick" and a.args[1] == "b2")
    assert st.prune([pick], picked)


def test_a_goal_region_with_something_else_on_it_is_cleared_first():
    problem = ground_scene(scene("obstacles_tower_pr2"), manipulators=["right_arm"])
    st = Stacking(problem, {"goal_region"})
    assert st.active
    assert set(st.unfinished(problem.init, {"b1", "b2", "b3", "b4"})) == {"o1", "o2"}
    # without knowing it is a region (a fixture's top takes anything), nothing is cleared off it
    assert Stacking(problem).unfinished(problem.init, {"b1", "b2", "b3", "b4"}) == []


def test_flat_objects_on_the_table_are_not_refused_by_the_tool_sphere():
    from rlgp_exec.planning.sequence import SequenceGeometry

    apart = {"d_mid": (0.3, 0.0, 0.735, 0.0), "d_small": (0.0, 0.0, 0.735, 0.0)}  # off the large disc
    for name, obj in (("tower_pr2", "b1"), ("hanoi_pr2", "d_large")):
        sc = scene(name)
        if name == "hanoi_pr2":
            sc = sc.with_object_poses(apart)
        geo = SequenceGeometry(sc)
        try:
            manip = goal_manipulator(sc)
            args = (geo.model, sc, [Action("pick", obj)], manip, (), geo.mesh_hand, 0.0, (), geo.tip_points)
            assert pinned_conflict(*args) is None
            # the tool sphere alone (no fingertip points, no finger spheres) still refuses it, naming the table
            refused = pinned_conflict(geo.model, sc, [Action("pick", obj)], manip)
            assert refused is not None and "table" in refused
            # a 5 mm plate: the fingertips would meet the table at every closing
            thin = replace(sc, objects=tuple(
                replace(o, size=(o.size[0], o.size[1], 0.005), pose=(*o.pose[:2], 0.7225, o.pose[3]))
                if o.name == obj else o for o in sc.objects))
            why = pinned_conflict(geo.model, thin, [Action("pick", obj)], manip, (), geo.mesh_hand, 0.0, (),
                                  geo.tip_points)
            assert why is not None and "table" in why
            # nor is the goal's reachability check (its IK keeps the tool sphere off the table)
            assert unreachable_goal(geo, ground_scene(sc, manipulators=[manip])) is None
        finally:
            geo.close()


def test_a_block_set_down_earlier_is_picked_where_the_plan_put_it():
    from rlgp_exec.planning.sequence import SequenceGeometry

    sc = scene("tower_pr2")
    geo = SequenceGeometry(sc)
    try:
        acts = [Action("pick", "b6"), Action("place", "b6", "goal_region"), Action("pick", "b6"),
                Action("place", "b6", "table")]
        kf = geo._solve_keyframes(sc, geo.q0, acts, 0.0, {})
        assert kf.ok, kf.reason
        T_placed = kf.object_poses[1]["b6"]
        assert np.linalg.norm(T_placed[:2, 3] - sc.object("b6").T[:2, 3]) > 0.1  # it did move
        tool = geo.model.fk(kf.keyframes[2], geo.tool)[:3, 3]
        b6 = sc.object("b6")
        expected = T_placed[:3, 3] + [0.0, 0.0, b6.size[2] / 2 - min(0.025, b6.size[2] / 2)]
        assert np.linalg.norm(tool - expected) < 1e-3, (tool, expected)
    finally:
        geo.close()


def test_world_model_knows_what_rests_on_what_and_carries_it():
    sc = scene("hanoi_pr2")
    assert stacks(sc) == {"d_large": ["d_mid", "d_small"], "d_mid": ["d_small"]}
    moved = sc.object("d_large").T.copy()
    moved[:3, 3] += [0.6, 0.0, 0.0]  # the bottom disc sensed on the right peg, the two above it not seen
    carried = carried_along(sc, {"d_large": moved})
    for name in ("d_mid", "d_small"):
        assert np.allclose(carried[name][:3, 3], sc.object(name).T[:3, 3] + [0.6, 0.0, 0.0])
    after = update_scene(sc, load_robot("pr2"), None, {"d_large": moved})
    assert after.object("d_small").support == "d_mid" and after.object("d_mid").support == "d_large"
    assert np.isclose(after.object("d_small").pose[0], 0.3)
    # what is sensed is where it is sensed; an object in the hand is not carried by what it stood on
    assert "d_mid" not in carried_along(sc, {"d_large": moved, "d_mid": sc.object("d_mid").T})
    assert carried_along(sc, {"d_large": moved}, held="d_mid") == {}


def test_nothing_is_set_down_on_a_goal_region_before_it_is_cleared():
    problem = ground_scene(scene("obstacles_tower_pr2"), manipulators=["right_arm"])
    st = Stacking(problem, {"goal_region"})
    state = problem.init
    for a, s in problem.successors(state):
        if a.name == "pick" and a.args[1] == "b1":
            put = next((x, t) for x, t in problem.successors(s) if x.name == "place" and x.args[2] == "goal_region")
            assert st.prune([a, put[0]], put[1])  # o1 and o2 still stand there
    # o1 and o2 moved to the table: b1 may go onto the region, o1 may not come back
    cleared = set(state) - {("on", "o1", "goal_region"), ("on", "o2", "goal_region")}
    cleared |= {("on", "o1", "table"), ("on", "o2", "table")}
    held_b1 = frozenset(cleared - {("on", "b1", "table"), ("clear", "b1"), ("hand-empty", "right_arm")}
                        | {("holding", "right_arm", "b1")})
    place_b1 = next((x, t) for x, t in problem.successors(held_b1) if x.name == "place" and x.args[2] == "goal_region")
    assert not st.prune([place_b1[0]], place_b1[1])
    held_o1 = frozenset(cleared - {("on", "o1", "table"), ("clear", "o1"), ("hand-empty", "right_arm")}
                        | {("holding", "right_arm", "o1")})
    place_o1 = next((x, t) for x, t in problem.successors(held_o1) if x.name == "place" and x.args[2] == "goal_region")
    assert st.prune([place_o1[0]], place_o1[1])
