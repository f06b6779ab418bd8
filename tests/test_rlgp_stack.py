"""R-LGP stacks: a three-block tower on the PR2 (pick_place_pr2's table and blocks, the goal a tower on
the tray) plans, validates by replay, and leaves each block resting on the one below."""

from __future__ import annotations

import itertools
import tomllib
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions import GEOMETRIC_ACTIONS, RELEASES, kind, parse_text
from rlgp_exec.planning.rlgp import _site, plan_scene, to_actions
from rlgp_exec.planning.symbolic.model import GroundAction
from rlgp_exec.planning.validate import ON_TOLERANCE
from rlgp_exec.scene.loader import scene_from_dict

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"
BLOCKS = ("block_a", "block_b", "block_c")


def parsed(plan) -> list[tuple[str, ...]]:
    """A plan's actions as (name, object, target...) words, from their "(name [arm] obj target)" text."""
    return [(w.name, w.obj, *([w.target] if w.target else [])) for w in map(parse_text, plan.actions)]


def tower_scene():
    data = tomllib.loads((SCENES / "pick_place_pr2.toml").read_text())
    data["scene"]["name"] = "tower3_pr2"
    data["goal"]["literals"] = ["(on block_a tray)", "(on block_b block_a)", "(on block_c block_b)"]
    return scene_from_dict(data, "tower3_pr2")


@pytest.fixture(scope="module")
def tower_plan():
    return plan_scene(tower_scene(), "rlgp")


def test_tower_plan_validates(tower_plan):
    assert tower_plan.success, tower_plan.reason
    assert tower_plan.validation is not None and tower_plan.validation.ok
    assert [w[0] for w in parsed(tower_plan)].count("stack") == 2


def test_replayed_blocks_rest_on_the_one_below(tower_plan):
    scene = tower_scene()
    poses = tower_plan.validation.final_poses
    for lower, upper in itertools.pairwise(BLOCKS):
        lo, up = scene.object(lower), scene.object(upper)
        bottom = poses[upper][2, 3] - up.size[2] / 2
        top = poses[lower][2, 3] + lo.size[2] / 2
        assert abs(bottom - top) <= ON_TOLERANCE, (upper, lower, bottom - top)
        d = np.linalg.solve(poses[lower], poses[upper][:, 3])  # the upper's centre in the lower's frame
        assert abs(d[0]) <= lo.size[0] / 2 and abs(d[1]) <= lo.size[1] / 2, (upper, lower, d[:2])
        assert poses[upper][2, 2] > 0.99  # upright


def test_no_stack_onto_a_block_that_is_not_clear(tower_plan):
    movables = {o.name for o in tower_scene().objects}
    on: dict[str, str] = {}
    for name, obj, *target in parsed(tower_plan):
        if name == "pick":
            on.pop(obj, None)
        elif name in RELEASES and target:
            if name == "stack" and target[0] in movables:
                assert target[0] not in on.values(), f"({name} {obj} {target[0]}): {on} already"
            on[obj] = target[0]


def test_stack_site_is_the_top_face_of_the_block_below():
    scene = tower_scene()

    class Geo:  # _site reads only the scene from the geometry
        pass

    geo = Geo()
    geo.scene = scene
    where = {o.name: np.array([0.1, 0.2, 0.9]) for o in scene.objects}
    a, b = scene.object("block_b"), scene.object("block_a")
    site = _site(geo, GroundAction("stack", ("right_arm", "block_b", "block_a")), where, {})  # type: ignore[arg-type]
    assert np.allclose(site, where["block_a"] + [0.0, 0.0, b.size[2] / 2 + a.size[2]])
    acts = to_actions([GroundAction("pick", ("right_arm", "block_b", "table")),
                       GroundAction("stack", ("right_arm", "block_b", "block_a"))])
    assert not isinstance(acts, str)
    assert (acts[1].name, acts[1].obj, acts[1].target) == ("stack", "block_b", "block_a")


def test_action_kinds_are_named_once():
    assert len(set(GEOMETRIC_ACTIONS)) == len(GEOMETRIC_ACTIONS)
    assert kind("stack").releases and kind("stack").sets_down
    with pytest.raises(RlgpError, match="valid"):
        kind("fly")
