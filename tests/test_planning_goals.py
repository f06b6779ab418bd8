"""Goals the planner cannot meet end with a clear result, bounded in work: an invalid goal before any
geometry, an unreachable object after a bounded number of keyframe NLPs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest

from rlgp_exec.errors import SceneError
from rlgp_exec.planning.rlgp import plan_scene
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.types import Goal, Literal

ROOT = Path(__file__).resolve().parent
SORTING = ROOT.parent / "sim" / "scenes" / "sorting_hsr.toml"
UNREACHABLE = ROOT / "data" / "unreachable_hsr.toml"


def test_a_goal_naming_a_missing_object_is_an_invalid_goal_before_any_geometry():
    scene = load_scene(SORTING)
    bad = replace(scene, goal=Goal((Literal("on", ("unicorn", "tray_blue")),)))
    for planner in ("rlgp", "lgp"):
        plan = plan_scene(bad, planner)
        assert not plan.success
        assert plan.reason.startswith("invalid goal") and "unicorn" in plan.reason and "block_blue" in plan.reason
        assert plan.n_nlp == 0 and plan.nodes_expanded == 0


def test_a_scene_file_with_a_missing_object_in_its_goal_is_rejected_naming_it(tmp_path):
    text = SORTING.read_text().replace('"(on block_green tray_green)"', '"(on block_red tray_green)"')
    path = tmp_path / "bad_goal.toml"
    path.write_text(text)
    with pytest.raises(SceneError, match="block_red"):
        load_scene(path)


def test_an_object_out_of_reach_makes_the_goal_infeasible_after_a_bounded_search():
    scene = load_scene(UNREACHABLE)
    plan = plan_scene(scene, "rlgp")
    assert not plan.success
    assert plan.reason.startswith("infeasible: block cannot be reached"), plan.reason
    # one candidate (two grasp tilts), then the pre-check: no search through the other candidates
    assert plan.n_nlp <= 2


NICHE = ROOT / "data" / "niche_hsr.toml"


def test_an_order_forced_by_reachability_is_found_and_the_other_order_fails():
    """The block at the back of the niche is reachable only once the tall box in front of it is gone
    (tests/data/niche_hsr.toml): block first fails at the geometric levels, rlgp plans box first."""
    from rlgp_exec.planning.nlp.action import Action
    from rlgp_exec.planning.sequence import SequenceGeometry

    scene = load_scene(NICHE)
    geo = SequenceGeometry(scene)
    try:
        block_first = geo.plan_actions(
            [
                Action("pick", "block"),
                Action("place", "block", "tray_block"),
                Action("pick", "box"),
                Action("place", "box", "tray_box"),
            ]
        )
    finally:
        geo.close()
    assert not block_first.success
    plan = plan_scene(scene, "rlgp")
    assert plan.success, plan.reason
    assert plan.validation is not None and plan.validation.collision_free and plan.validation.goal_met
    assert plan.actions == ("(pick box)", "(place box tray_box)", "(pick block)", "(place block tray_block)")


def test_a_goal_that_already_holds_is_an_empty_valid_plan(tmp_path):
    src = (ROOT / "data" / "shelf_hsr.toml").read_text()
    path = tmp_path / "already.toml"
    path.write_text(src.replace('literals = ["(on block tray)"]', 'literals = ["(on block table)"]'))
    plan = plan_scene(load_scene(path))
    assert plan.success and plan.actions == () and plan.reason == "the goal already holds"
    assert plan.validation is not None and plan.validation.goal_met


# ------------------------------------------------------------------ a start state mid-task (replans)
def _held_after_first_pick(scene):
    """The sensed world after a full plan's first pick and its vertical leave: (robot state, poses, held)."""
    import numpy as np

    from rlgp_exec.hal.types import RobotState
    from rlgp_exec.robot import load_robot

    full = plan_scene(scene)
    assert full.success, full.reason
    model = load_robot(scene.robot.name)
    k = next(i for i, ph in enumerate(full.phases) if ph.grasp)
    obj, q_grasp, q_up = full.phases[k].grasp, full.phases[k].path[-1], full.phases[k + 1].path[-1]
    tool = model.manipulator().tool_frame
    T_tool_obj = np.linalg.inv(model.fk(q_grasp, tool)) @ scene.object(obj).T
    names = [n for n in model.joint_names if n not in ("base_x", "base_y", "base_yaw")]
    state = RobotState(0.0, names, [q_up[model.index(n)] for n in names], np.zeros(len(names)), base=tuple(q_up[:3]))
    poses = {o.name: o.T for o in scene.objects} | {obj: model.fk(q_up, tool) @ T_tool_obj}
    return model, state, poses, obj


def test_a_plan_starts_with_the_object_in_the_hand_and_sets_it_down_first():
    from rlgp_exec.executive.world import update_scene
    from rlgp_exec.planning.registry import plan as run_planner
    from rlgp_exec.planning.symbolic.problem import problem_from_scene

    scene = load_scene(SORTING)
    model, state, poses, obj = _held_after_first_pick(scene)
    start = update_scene(scene, model, state, poses, held=obj, openings={})
    assert start.start.held == obj and start.object(obj).support == "<hand>"
    init = problem_from_scene(start, manipulators=["arm"]).init
    assert ("holding", "arm", obj) in init and ("hand-empty", "arm") not in init
    assert not any(a[0] == "on" and a[1] == obj for a in init)
    plan = plan_scene(start)
    assert plan.success, plan.reason
    assert plan.actions[0].startswith(f"(place {obj} ") and f"(pick {obj})" not in plan.actions
    assert plan.phases[0].held == obj and plan.validation is not None and plan.validation.goal_met
    # GNPP's model starts from empty hands: it says so instead of planning a pick of what is held
    refused = run_planner(start, "gnpp")
    assert not refused.success and refused.reason.startswith("unsupported start: holding")


def test_a_plan_starts_with_a_drawer_out_and_closes_it():
    from rlgp_exec.scene import StartState

    scene = load_scene(ROOT.parent / "sim" / "scenes" / "table_clearing_hsr.toml")
    goal = Goal((Literal("closed", ("cabinet",)),))
    assert plan_scene(replace(scene, goal=goal)).actions == ()  # closed in the file: nothing to do
    plan = plan_scene(replace(scene, goal=goal, start=StartState(openings=(("cabinet", 0.3),))))
    assert plan.success, plan.reason
    assert plan.actions == ("(take_knob cabinet)", "(close_drawer cabinet)")
    assert plan.validation is not None and plan.validation.final_openings["cabinet"] < 0.01


def test_the_planners_budget_clock_counts_cpu_not_waiting():
    """R-LGP's and GNPP's budgets run on ``cpu_clock``: time spent waiting (a loaded machine, a sleep)
    does not use them up; computing does."""
    import time

    from rlgp_exec.planning.budget import cpu_clock

    c0 = cpu_clock()
    time.sleep(0.4)
    assert cpu_clock() - c0 < 0.1
    c1, t1 = cpu_clock(), time.perf_counter()
    n = 0
    while time.perf_counter() - t1 < 0.4:
        n += 1
    assert cpu_clock() - c1 > 0.0 and n > 0
