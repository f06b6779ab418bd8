"""Grasps in clutter: pick feasibility from the open fingers' own geometry against the neighbours."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.hand import finger_spheres, mesh_finger_spheres
from rlgp_exec.planning.nlp.keyframes import pinned_conflict
from rlgp_exec.planning.nlp.pick_fingers import palm_box_spheres
from rlgp_exec.reach.build import nominal_q
from rlgp_exec.reach.checker import WorldChecker
from rlgp_exec.robot.model import load_robot
from rlgp_exec.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"
PICK = [Action("pick", "block_target", "table"), Action("place", "block_target", "tray")]


def _hand(scene):
    model = load_robot(scene.robot.name)
    q0 = nominal_q(model, scene)
    checker = WorldChecker(scene, model.manipulator().group)
    return model, (finger_spheres(checker.robot, model, q0), mesh_finger_spheres(checker.robot, model, q0),
                   palm_box_spheres(checker.robot, model, q0))


def _boxed_in(tmp_path: Path, robot: str) -> Path:
    """The clutter scene with two more neighbours 1 cm from the target, on its free sides."""
    text = (SCENES / f"clutter_{robot}.toml").read_text()
    z, h = ("0.77", "0.10") if robot == "pr2" else ("0.49", "0.08")
    for name, y in (("block_near", -0.11), ("block_far", 0.01)):
        text = text.replace("[goal]", f'[[object]]\nname = "{name}"\nsize = [0.05, 0.05, {h}]\n'
                                      f"pose = [-0.15, {y}, {z}, 0.0]\ncolor = \"grey\"\n\n[goal]")
    out = tmp_path / f"boxed_in_{robot}.toml"
    out.write_text(text)
    return out


@pytest.mark.parametrize("robot", ["pr2", "hsr"])
def test_fingers_fit_across_the_free_sides_where_the_tool_sphere_did_not(robot):
    scene = load_scene(SCENES / f"clutter_{robot}.toml")
    model, (hand, mesh, palm) = _hand(scene)
    assert hand or mesh  # the robot's fingers have spheres of their own
    assert pinned_conflict(model, scene, PICK, None, hand, mesh, 0.0, palm) is None
    # the tool sphere alone (no finger geometry) refuses the same grasp, naming a neighbour
    coarse = pinned_conflict(model, scene, PICK)
    assert coarse is not None and "block_left" in coarse


@pytest.mark.parametrize("robot", ["pr2", "hsr"])
def test_a_block_boxed_in_on_all_four_sides_is_refused_naming_the_neighbours(robot, tmp_path):
    scene = load_scene(_boxed_in(tmp_path, robot))
    model, (hand, mesh, palm) = _hand(scene)
    for tilt in (0.0, 0.6):
        why = pinned_conflict(model, scene, PICK, None, hand, mesh, tilt, palm)
        assert why is not None and "(pick block_target" in why and "open fingers hit" in why
        assert any(n in why for n in ("block_left", "block_right", "block_near", "block_far")), why


@pytest.mark.parametrize("robot", ["pr2", "hsr"])
def test_clutter_scene_plans_with_the_fingers_closing_across_the_free_sides(robot):
    from rlgp_exec.planning.rlgp import plan_scene

    scene = load_scene(SCENES / f"clutter_{robot}.toml")
    plan = plan_scene(scene, "rlgp")
    assert plan.success, plan.reason
    v = plan.validation
    assert v is not None and v.collision_free and v.goal_met
    model = load_robot(scene.robot.name)
    manip = model.manipulator()
    k = next(i for i, a in enumerate(plan.actions) if a.startswith("(pick") and "block_target" in a)
    c = model.fk(plan.keyframes[k], manip.tool_frame)[:3, :3] @ np.asarray(manip.closing, float)
    # the neighbours stand along world x: the fingers close along y, over the free sides
    assert abs(c[0]) < 0.1 * np.linalg.norm(c[:2]), c
    for name in ("block_left", "block_right"):  # the neighbours were not pushed
        assert np.linalg.norm(v.final_poses[name][:3, 3] - scene.object(name).T[:3, 3]) < 1e-3


@pytest.mark.parametrize("robot", ["pr2"])  # the HSR's open fingers (25 cm) reach over 5 cm neighbours
def test_the_replay_rejects_fingers_turned_towards_a_neighbour(robot):
    from dataclasses import replace

    from rlgp_exec.planning.rlgp import plan_scene
    from rlgp_exec.planning.validate import validate_plan

    scene = load_scene(SCENES / f"clutter_{robot}.toml")
    plan = plan_scene(scene, "rlgp")
    assert plan.success, plan.reason
    model = load_robot(scene.robot.name)
    arm = [model.joint_names[i] for i in model.group(model.manipulator().group)]
    roll = model.joint_names.index(next(n for n in arm if "wrist_roll" in n))
    k = next(i for i, ph in enumerate(plan.phases) if ph.grasp == "block_target")
    path = plan.phases[k].path.copy()
    path[-1, roll] += np.pi / 2  # the same grasp point, the fingers closing towards the neighbours
    phases = list(plan.phases)
    phases[k] = replace(phases[k], path=path)
    v = validate_plan(scene, phases[: k + 1])
    assert not v.collision_free
    assert any("block_left" in c or "block_right" in c for c in v.collisions), v.collisions
