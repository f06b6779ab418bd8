"""Small tasks a lab writes itself, planned end to end and validated by replay: cylinders and boxes of
several sizes, supports at several heights."""

from __future__ import annotations

from pathlib import Path

from rlgp_exec.planning.registry import plan
from rlgp_exec.planning.transport import APPROACH, MIN_RISE
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene

DATA = Path(__file__).resolve().parent / "data"


def _validated(p) -> None:
    assert p.success, p.reason
    assert p.validation is not None and p.validation.collision_free and p.validation.goal_met


def test_a_cylinder_goes_from_a_low_table_onto_a_desk_with_the_lift_high():
    """A cylinder is grasped with a vertical hand only (it would pivot in a leaning one), and on the HSR a
    vertical hand reaches a 0.70 m desk only with the lift less than ``APPROACH`` below its top: the
    keyframe keeps the ``MIN_RISE`` the vertical leave needs, not more."""
    scene = load_scene(DATA / "cup_desk_hsr.toml")
    p = plan(scene, planner="rlgp", seed=0)
    _validated(p)
    assert p.actions == ("(pick cup)", "(place cup plate)")
    model = load_robot("hsr")
    i = model.index("arm_lift_joint")
    lift_place = float(p.keyframes[1][i])
    upper = float(model.limits.upper[i])
    assert upper - APPROACH < lift_place <= upper - MIN_RISE + 1e-6


def test_the_same_task_with_a_box_plans_too(tmp_path):
    src = (DATA / "cup_desk_hsr.toml").read_text()
    path = tmp_path / "box_desk_hsr.toml"
    path.write_text(src.replace('shape = "cylinder"', 'shape = "box"'))
    scene = load_scene(path)
    assert scene.object("cup").shape == "box"
    _validated(plan(scene, planner="rlgp", seed=0))


def test_a_box_goes_onto_a_counter_whose_place_leaves_the_lift_its_least_rise():
    """On a 0.85 m counter the place keyframe's lift row is active (``MIN_RISE`` below the top, to the NLP's
    tolerance): the vertical leave is then the lift's last ``MIN_RISE``, not refused for a hair over the top."""
    p = plan(load_scene(DATA / "box_counter_hsr.toml"), planner="rlgp", seed=0)
    _validated(p)
    assert p.actions == ("(pick box)", "(place box mat)")


def test_a_target_beside_a_fixed_base_is_planned_by_rlgp_and_gnpp_says_its_base_stays():
    """GNPP keeps the PR2's base at its start; the stool is within the arms' reach bound that ``refuse``
    checks, so GNPP's search proves the task infeasible, and says why that may be."""
    scene = load_scene(DATA / "cup_stool_pr2.toml")
    g = plan(scene, planner="gnpp", seed=0)
    assert not g.success
    assert g.reason.startswith("infeasible") and "base stays at its start" in g.reason, g.reason
    assert "rlgp drives the base" in g.reason
    _validated(plan(scene, planner="rlgp", seed=0))


def test_three_objects_of_two_shapes_go_onto_bins_on_a_desk_and_a_bench():
    p = plan(load_scene(DATA / "mixed_three_hsr.toml"), planner="rlgp", seed=0)
    _validated(p)
    assert sorted(a for a in p.actions if a.startswith("(place")) == [
        "(place brick bin_low)", "(place can bin_desk)", "(place glass bin_low)"]
