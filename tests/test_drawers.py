"""Drawer cabinets in the planners: the knob and the drop area at an opening, the replay moving the
drawer with the hand on the knob (and what lies in it), a dropped object falling onto the drawer's
floor, the in/open/closed goals, and a whole table-clearing plan validated by replay."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.drawer_replay import DrawerMotion, drawer_literal_holds, settle
from rlgp_exec.planning.drawers import drawer_view
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.keyframes import solve_keyframes
from rlgp_exec.planning.validate import Phase, validate_plan
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.types import Literal

CLEARING = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "table_clearing_hsr.toml"


@pytest.fixture(scope="module")
def scene():
    return load_scene(CLEARING)


def test_knob_and_drop_area_follow_the_opening(scene):
    v = drawer_view(scene, "cabinet")
    d = v.travel
    assert np.allclose(v.T_world_knob(d)[:3, 3] - v.T_world_knob(0.0)[:3, 3], d * v.axis_world)
    T, half = v.drop_rect(d, 0.03)
    assert half[0] > 0 and half[1] > 0
    # the drop area lies over the drawer's floor and in front of the carcass (the part pulled out)
    front = scene.fixture("cabinet").T @ np.array([scene.fixture("cabinet").size[0] / 2, 0, 0, 1])
    assert (front[:3] - T[:3, 3]) @ v.axis_world < 0  # on the open side of the carcass front
    assert abs(T[2, 3] - v.floor_z(d)) < 1e-9
    with pytest.raises(Exception, match="no room"):
        v.drop_rect(0.02, 0.03)


def test_the_replay_opens_the_drawer_with_the_hand_and_catches_leaving_its_axis(scene):
    from rlgp_exec.planning.sequence import SequenceGeometry

    geo = SequenceGeometry(scene)
    model = geo.model
    acts = [Action("take_knob", "cabinet"), Action("open_drawer", "cabinet")]
    try:
        kf = solve_keyframes(
            model, scene, geo.q0, acts, in_collision=geo._in_collision, ik=geo.ik, hand=geo.hand,
            self_spheres=geo.self_spheres, body=geo.body,
        )
    finally:
        geo.close()
    assert kf.ok, kf.reason
    q_take, q_open = kf.keyframes
    assert kf.openings[1]["cabinet"] == pytest.approx(0.3)
    v = drawer_view(scene, "cabinet")
    tool = model.manipulator().tool_frame
    # the articulated constraint: the hand moved exactly with the knob
    moved = model.fk(q_open, tool)[:3, 3] - model.fk(q_take, tool)[:3, 3]
    assert np.allclose(moved, 0.3 * v.axis_world, atol=1e-4)
    q_back = q_open.copy()
    q_back[:2] += 0.1 * v.axis_world[:2]
    phases = [
        Phase(np.array([q_take, q_take]), None, knob="cabinet"),
        Phase(np.array([q_take, q_open]), None, knob="cabinet", drives_drawer=True),
        Phase(np.array([q_open, q_back]), None, knob="cabinet"),
    ]
    goal_open = replace(scene, goal=replace(scene.goal, literals=(Literal("open", ("cabinet",)),)))
    res = validate_plan(goal_open, phases)
    assert res.collision_free, res.collisions
    assert res.final_openings["cabinet"] == pytest.approx(0.3, abs=1e-3) and res.goal_met
    assert not validate_plan(scene, phases).goal_met  # the scene's goal wants it closed, objects in
    skew = q_open.copy()
    skew[:2] += 0.03 * np.array([-v.axis_world[1], v.axis_world[0]])  # 3 cm across the axis
    skewed = Phase(np.array([q_take, skew]), None, knob="cabinet", drives_drawer=True)
    bad = validate_plan(goal_open, [phases[0], skewed])
    assert not bad.collision_free and any("leaves the drawer's axis" in c for c in bad.collisions)


def test_a_dropped_object_lands_in_the_drawer_and_rides_with_it(scene):
    from rlgp_exec.world.pybullet_world import build_world

    v = drawer_view(scene, "cabinet")
    world = build_world(scene, tags=False)
    try:
        world.set_drawer_opening("cabinet", v.travel)
        T_rect, _ = v.drop_rect(v.travel, 0.03)
        T = np.eye(4)
        T[:3, 3] = T_rect[:3, 3] + [0.0, 0.0, 0.2]  # released 20 cm above the floor
        world.set_object_pose("block", T)
        fallen = settle(world, "block", world.robot.id, 2e-3)
        assert fallen > 0.1
        size = scene.object("block").size
        ok, why = v.holds(world.object_pose("block"), size, v.travel)
        assert ok, why
        T_tool = np.eye(4)
        T_tool[:3, 3] = v.T_world_knob(v.travel)[:3, 3]
        motion = DrawerMotion.start(world, "cabinet", T_tool)
        assert set(motion.riders) == {"block"}
        T_tool[:3, 3] -= v.travel * v.axis_world  # push it shut
        assert motion.follow(world, T_tool) is None
        poses = {n: world.object_pose(n) for n in world.objects}
        openings = {"cabinet": world.drawer_opening("cabinet")}
    finally:
        world.close()
    for lit in (Literal("in", ("block", "cabinet")), Literal("closed", ("cabinet",))):
        ok, why = drawer_literal_holds(scene, lit, poses, openings)
        assert ok, why
    ok, _ = drawer_literal_holds(scene, Literal("in", ("cup", "cabinet")), poses, openings)
    assert not ok  # the cup is still on the cabinet's top


def test_table_clearing_plan_is_valid_under_replay(scene):
    from rlgp_exec.planning.rlgp import plan_scene

    plan = plan_scene(scene, "rlgp")
    assert plan.success, plan.reason
    v = plan.validation
    assert v is not None and v.collision_free and v.goal_met
    assert v.final_openings["cabinet"] <= 0.005
    names = [a.split()[0].lstrip("(") for a in plan.actions]
    assert names[:2] == ["take_knob", "open_drawer"] and names[-2:] == ["take_knob", "close_drawer"]
    assert sorted(names[2:-2]) == ["drop", "drop", "pick", "pick"]
    # each action is completed by one phase, in order, whose end is what the action does (the executive's
    # record of what was carried out): the grasp, the release, the drawer driven, the hand on the knob
    done = [(k, ph) for k, ph in enumerate(plan.phases) if ph.action is not None]
    assert [ph.action for _, ph in done] == list(range(len(plan.actions)))
    for _, ph in done:
        name, obj = plan.actions[ph.action].strip("()").split()[:2]
        drives = ph.drives_drawer and ph.knob == obj
        expect = {"pick": ph.grasp == obj, "drop": ph.release == obj and ph.fall,
                  "take_knob": ph.knob == obj and not ph.drives_drawer, "open_drawer": drives, "close_drawer": drives}
        assert expect[name], (plan.actions[ph.action], ph)
