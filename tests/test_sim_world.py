"""PyBullet worlds from the shipped scenes: they build, start collision-free, and render."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pybullet as p
import pytest

from rlgp_exec.cli import main
from rlgp_exec.demo import scene_path
from rlgp_exec.errors import RlgpError
from rlgp_exec.scene import load_scene, randomize
from rlgp_exec.world.pybullet_world import build_world
from rlgp_exec.world.render import render_world

SCENES = sorted(f.stem for f in (Path(__file__).resolve().parents[1] / "sim" / "scenes").glob("*.toml"))


def test_the_paper_scenes_are_shipped():
    assert {"pick_place_pr2", "sorting_pr2", "sorting_hsr", "table_clearing_hsr", "tower_pr2", "hanoi_pr2",
            "obstacles_tower_pr2"} <= set(SCENES)


@pytest.mark.parametrize("name", SCENES)
def test_scene_builds_without_initial_collisions(name):
    scene = load_scene(scene_path(name))
    for s in [scene] + [randomize(scene, seed) for seed in range(3)]:
        world = build_world(s, tags=False)
        try:
            assert world.penetrations() == [], (name, s.name)
            assert set(world.objects) == {o.name for o in s.objects}
            for o in s.objects:  # the bodies sit where the scene says
                T = world.object_pose(o.name)
                assert np.allclose(T[:3, 3], o.pose[:3], atol=1e-6)
        finally:
            world.close()


def test_robot_starts_at_the_scene_base_pose():
    scene = load_scene(scene_path("sorting_hsr"))
    world = build_world(scene, tags=False)
    try:
        q = world.robot.get_q()
        assert np.allclose(q[:3], scene.robot.base, atol=1e-9)
    finally:
        world.close()


def test_drawer_slides_along_its_axis_within_travel():
    scene = load_scene(scene_path("table_clearing_hsr"))
    world = build_world(scene, tags=False)
    try:
        (name, cab), = world.cabinets.items()
        link_closed = np.array(p.getLinkState(cab.body, cab.drawer_joint, physicsClientId=world.client)[4])
        world.set_drawer_opening(name, cab.travel)
        link_open = np.array(p.getLinkState(cab.body, cab.drawer_joint, physicsClientId=world.client)[4])
        assert np.linalg.norm(link_open - link_closed) == pytest.approx(cab.travel, abs=1e-6)
        assert abs(link_open[2] - link_closed[2]) < 1e-9  # horizontal
        assert world.drawer_opening(name) == pytest.approx(cab.travel)
        assert world.penetrations() == []  # the open drawer clears the robot at its start pose
        with pytest.raises(RlgpError, match="outside"):
            world.set_drawer_opening(name, cab.travel + 0.1)
    finally:
        world.close()


def test_penetration_report_names_the_bodies():
    scene = load_scene(scene_path("pick_place_pr2"))
    world = build_world(scene, tags=False)
    try:
        a, b = list(world.objects)[:2]
        world.set_object_pose(a, world.object_pose(b))
        report = world.penetrations()
        assert any(a in r and b in r for r in report)
    finally:
        world.close()


def test_robot_camera_view_renders_the_scene():
    scene = load_scene(scene_path("sorting_hsr"))
    world = build_world(scene, tags=False)
    try:
        rgb = render_world(world, 320, 240, "robot")
        assert rgb.shape == (240, 320, 3) and rgb.dtype == np.uint8
        assert rgb.std() > 5.0  # not a blank frame
    finally:
        world.close()


def test_show_writes_a_png_with_the_scene_colours(tmp_path):
    out = tmp_path / "scene.png"
    assert main(["show", str(scene_path("table_clearing_hsr")), "--png", str(out), "--width", "480",
                 "--height", "360"]) == 0
    img = cv2.imread(str(out))
    assert img is not None and img.shape == (360, 480, 3)
    assert len(np.unique(img.reshape(-1, 3) // 32, axis=0)) > 8  # many distinct colours, not a flat image


def test_cli_reports_bad_scene_files_with_exit_code_2(tmp_path, capsys):
    bad = tmp_path / "bad.toml"
    bad.write_text('[scene]\nname = "x"\nrobot = "nao"\n')
    assert main(["show", str(bad), "--png", str(tmp_path / "x.png")]) == 2
    err = capsys.readouterr().err
    assert "bad.toml" in err and "robot" in err


def test_cli_plan_writes_the_contract_json_and_the_base_path_plot(tmp_path):
    """``rlgp-exec plan SCENE --json F --plot F`` (DESIGN.md's command-line contract)."""
    import json

    shelf = Path(__file__).resolve().parent / "data" / "shelf_hsr.toml"
    js, png = tmp_path / "plan.json", tmp_path / "plan.png"
    assert main(["plan", str(shelf), "--json", str(js), "--plot", str(png)]) == 0
    out = json.loads(js.read_text())
    for key in (
        "success",
        "planner",
        "planning_time_s",
        "actions",
        "n_steps",
        "base_path_length_m",
        "collision_free",
        "n_nlp",
    ):
        assert key in out, key
    assert out["success"] and out["collision_free"] and out["actions"] == ["(pick block)", "(place block tray)"]
    img = cv2.imread(str(png))
    assert img is not None and img.shape[0] > 200 and out["plot"] == str(png)


def test_cli_perceive_then_plan_checks_the_plan_in_the_true_world(tmp_path, capsys):
    """``rlgp-exec perceive SCENE --plan rlgp`` (what the numbered tools/1x scripts run): objects 3 cm
    off the file, perceived, planned on, the plan replayed in the true world."""
    import json

    shelf = Path(__file__).resolve().parent / "data" / "shelf_hsr.toml"
    js = tmp_path / "pp.json"
    assert main(["perceive", str(shelf), "--plan", "rlgp", "--perturb", "0.03", "--json", str(js)]) == 0
    run = json.loads(js.read_text())["runs"][0]
    assert run["success"] and run["true_world_collision_free"] and run["true_world_goal_met"] and run["ok"]
    assert run["pos_err_mm"]["block"] < 3.0 and run["unseen"] == []
    assert "in the true world: collision-free, goal met" in capsys.readouterr().out


def test_run_refuses_perception_off_the_simulator(capsys):
    assert main(["run", str(scene_path("sorting_hsr")), "--perceive", "--backend", "zenoh"]) == 2
    assert "--perceive" in capsys.readouterr().err


def test_demo_sorting_hsr_over_zenoh_reaches_the_goal(tmp_path):
    """The dry run end to end: a sim-robot process over Zenoh, sensing by its head camera, R-LGP, TOPPRA +
    Ruckig; the report gives each object's final error against the true world."""
    from rlgp_exec.demo import run_demo
    from rlgp_exec.executive import read_recording

    report = run_demo(tmp_path, seed=1, scene_name="sorting_hsr")  # (make demo: table clearing, ~6 min)
    assert report.ok, report.text()
    assert [s.name for s in report.stages] == ["scene", "world", "perceive", "robot", "camera", "executive", "replay"]
    assert "goal holds in the sensed world" in report.text()
    executive = next(s for s in report.stages if s.name == "executive").detail
    assert "objects sensed by the head camera" in executive
    assert executive.count("mm from the truth") == 2, executive  # block_blue and block_green
    assert all(f.is_file() and f.stat().st_size > 1000 for f in report.files)
    rec = read_recording(tmp_path / "demo.mcap")
    assert rec.complete and rec.topic("/events")[-1][1]["status"] == "succeeded"


def test_the_simulated_pr2_holds_its_torso_and_arm_up_against_gravity():
    """The joint motors carry the robot's weight: the PR2's torso (~1200 N) sagged 14 cm below its
    setpoint with a flat 300 N motor, and the plans' hand heights with it; the raised arm holds too."""
    import numpy as np

    from rlgp_exec.hal.sim_physics import SimRobot
    from rlgp_exec.hal.types import JointSetpoint

    sim = SimRobot("pr2")
    m = sim.model
    names = ("torso_lift_joint", "r_shoulder_lift_joint")
    q = sim.measured_q()
    target = np.array([q[m.index(n)] for n in names]) + np.array([0.1, -0.3])  # torso up, arm raised
    for k in range(1, 301):  # 3 s: torso at 0.013 m/s needs ~8 s for 10 cm; ramp the target
        s = min(1.0, k / 200)
        q_now = np.array([q[m.index(n)] for n in names])
        sim.set_joint_targets(JointSetpoint(names, q_now + s * (target - q_now), np.zeros(2)))
        sim.step(0.01)
    for _ in range(1000):  # then hold 10 s
        sim.set_joint_targets(JointSetpoint(names, target, np.zeros(2)))
        sim.step(0.01)
    got = np.array([sim.measured_q()[m.index(n)] for n in names])
    assert np.all(np.abs(got - target) < 0.01), dict(zip(names, got - target, strict=True))


def test_a_continuous_joint_crosses_pi_the_short_way():
    """Setpoints arrive wrapped to [-pi, pi): the PR2's forearm roll going -3.0 -> -3.3 (= +2.98) must
    turn 0.3 rad on, not spin a turn back (it did: the executive stopped, 0.155 rad off while carrying)."""
    import math

    from rlgp_exec.hal.sim_physics import SimRobot
    from rlgp_exec.hal.types import JointSetpoint
    from rlgp_exec.robot.limits import wrap_angle

    sim = SimRobot("pr2")
    i = sim.model.index("r_forearm_roll_joint")
    names = ("r_forearm_roll_joint",)
    for k in range(301):  # to -3.0 in 1 s, hold, then on to -3.3 through -pi at 0.3 rad/s
        a = -3.0 * min(1.0, k / 100) if k <= 200 else -3.0 - 0.3 * min(1.0, (k - 200) / 100)
        sim.set_joint_targets(JointSetpoint(names, (float(wrap_angle(a)),), (0.0,)))
        sim.step(0.01)
        if k > 200:
            err = abs(math.remainder(sim.measured_q()[i] - a, 2 * math.pi))
            assert err < 0.05, (k, a, sim.measured_q()[i])
    for _ in range(100):
        sim.step(0.01)
    assert abs(math.remainder(sim.measured_q()[i] - (-3.3), 2 * math.pi)) < 0.01
    assert -math.pi <= sim.measured_q()[i] < math.pi  # reported wrapped


@pytest.mark.parametrize("robot", ["pr2", "hsr"])
def test_a_grasped_object_keeps_its_pose_in_the_hand_while_the_arm_moves(robot):
    """GRASP fixes the object to the palm where the fingers closed on it: lifted and swung under gravity it
    stays put in the tool frame (within 2 mm). A constraint's frames are the links' centres of mass: the
    PR2's palm has its own 6.6 cm out along the tool axis, and a frame taken as the palm's URDF pose let
    every held block slide that far down the fingers (carried 6.6 cm below the planned grasp)."""
    from rlgp_exec.hal.sim_physics import SimRobot
    from rlgp_exec.hal.types import GripperCommand, JointSetpoint
    from rlgp_exec.robot.pybullet_body import quat_xyzw

    sim = SimRobot(robot)
    try:
        c, man = sim.client, sim.model.manipulator()
        p.setGravity(0, 0, 0, physicsClientId=c)  # the block waits between the open fingers
        sim.step(1.0)
        T_tool = sim.robot.link_pose(man.tool_frame)
        approach, closing = np.asarray(man.approach, float), np.asarray(man.closing, float)
        third = np.cross(approach, closing)
        R = T_tool[:3, :3] @ np.column_stack([approach, closing, third])  # block x y z: approach, closing, third
        centre = T_tool[:3, 3] + T_tool[:3, :3] @ (0.025 * approach)  # 2.5 cm into the hand, as a top grasp
        half = [0.05, 0.025, 0.025]
        block = p.createMultiBody(
            0.1, p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=c), -1, centre.tolist(),
            quat_xyzw(R), physicsClientId=c,
        )
        sim.objects["block"] = block
        T_grasp = np.linalg.inv(T_tool) @ sim.object_pose("block")  # where the fingers close on it
        assert sim.gripper(GripperCommand.grasp(10.0))
        sim.step(1.5)
        assert sim.held == "block"
        p.setGravity(0, 0, -9.81, physicsClientId=c)
        idx = [i for i in sim.model.group(man.group) if i >= 3]  # the arm's joints (not a base's)
        names = [sim.model.joint_names[i] for i in idx]
        q = sim.measured_q()[idx]
        lo, hi = sim.model.limits.lower[idx], sim.model.limits.upper[idx]
        worst = 0.0
        for k in range(1, 5):  # the arm swings, each joint a little, four times
            target = np.clip(q + 0.15 * (-1) ** k, lo + 0.01, hi - 0.01)
            assert sim.set_joint_targets(JointSetpoint(names, target))
            for _ in range(20):
                sim.step(0.05)
                T = np.linalg.inv(sim.robot.link_pose(man.tool_frame)) @ sim.object_pose("block")
                worst = max(worst, float(np.linalg.norm(T[:3, 3] - T_grasp[:3, 3])))
        assert np.linalg.norm(sim.robot.link_pose(man.tool_frame)[:3, 3] - T_tool[:3, 3]) > 0.02  # it moved
        assert worst < 2e-3, worst
    finally:
        sim.close()
