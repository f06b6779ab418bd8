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
    from rlgp_exec.planning.nlp.keyframes import Action
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
