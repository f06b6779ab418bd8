"""Bad scene files end in a short, specific error, never a traceback: the reproducers in tests/data/bad-scenes
through the CLI, each scene rule at its bound, and a load-only fuzz of mutants of the shipped scenes."""

from __future__ import annotations

import copy
import math
import os
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rlgp_exec.errors import SceneError
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene, scene_from_dict
from rlgp_exec.scene.mutate import OPERATORS, dump_toml, mutants
from rlgp_exec.scene.rules import (
    ANGLE_MAX,
    COORD_MAX,
    FILE_BYTES_MAX,
    FIXTURE_SIZE_MAX,
    HEIGHT_MAX,
    JOINT_TOLERANCE,
    MESSAGE_MAX,
    OBJECT_SIZE_MAX,
    QUOTE_MAX,
    SIZE_MIN,
    WORKSPACE_RADIUS,
    quote,
)

ROOT = Path(__file__).resolve().parents[1]
BAD_DIR = ROOT / "tests" / "data" / "bad-scenes"
SCENES_DIR = ROOT / "sim" / "scenes"
MESSAGE_LIMIT = 500

#: reproducer -> (the key path the error names, the rule's words in it)
EXPECTED = {
    "arm_flex_100rad": ("[robot].joints.arm_flex_joint", "outside the joint's range [-2.62, 0] rad"),
    "arm_in_table_sorting_hsr": ("[robot].joints", "puts link 'hand_l_finger_link'"),
    "deep_nested_name": ("scene.name.k0", "NESTING_MAX"),
    "fixture_z_minus_1e30": ("[[fixture]] 'table_green'.pose", "not below the floor"),
    "invalid_utf8": ("(file)", "not UTF-8 text: byte 0xff at line 6"),
    "robot_1000km_table_clearing_hsr": ("[robot].base", "COORD_MAX"),
    "robot_inside_cabinet": ("[robot].base", "starts inside fixture 'cabinet'"),
    "tiny_block_pick_place_pr2": ("[[object]] 'block_c'.size", "SIZE_MIN"),
    "tiny_cup_table_clearing_hsr": ("[[object]] 'cup'.size", "SIZE_MIN"),
    "truncated_no_goal_tower_pr2": ("[goal]", "missing"),
}


def test_every_reproducer_has_an_expectation():
    assert sorted(p.stem for p in BAD_DIR.glob("*.toml")) == sorted(EXPECTED)


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_reproducer_is_refused_by_the_cli_with_a_short_specific_message(name):
    path = BAD_DIR / f"{name}.toml"
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    res = subprocess.run([sys.executable, "-m", "rlgp_exec", "plan", str(path)], capture_output=True, text=True,
                         env=env, cwd=ROOT, timeout=60)
    assert res.returncode == 2, res.stderr[-500:]
    assert "Traceback" not in res.stderr
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("rlgp-exec plan: error: ")]
    assert len(lines) == 1, res.stderr[-500:]
    where, rule = EXPECTED[name]
    assert lines[0].startswith(f"rlgp-exec plan: error: {name}.toml: {where}"), lines[0]
    assert rule in lines[0] and len(lines[0]) < MESSAGE_LIMIT, lines[0]
    assert res.stdout == ""  # refused before any planning


# --------------------------------------------------------------------------- each rule at its bound
def raw(name: str) -> dict:
    return tomllib.loads((SCENES_DIR / f"{name}.toml").read_text())


def refusal(data: dict) -> str | None:
    """The error of ``data`` as a scene, None if it loads."""
    try:
        scene_from_dict(data, "t.toml")
    except SceneError as e:
        return str(e)
    return None


def edited(name: str, fn) -> dict:
    d = copy.deepcopy(raw(name))
    fn(d)
    return d


def _set_size(d, i, k, v):
    d["object"][i]["size"][k] = v
    d["object"][i].pop("tag", None)  # a tag needs a wider top face


def _cup(d, v):  # the table-clearing cup is a cylinder: both diameters together
    d["object"][0]["size"][:2] = [v, v]


def test_object_size_bounds():
    assert refusal(edited("pick_place_pr2", lambda d: _set_size(d, 0, 1, SIZE_MIN))) is None
    msg = refusal(edited("pick_place_pr2", lambda d: _set_size(d, 0, 1, SIZE_MIN * 0.9)))
    assert msg is not None and ".size: y extent" in msg and "[0.005, 1]" in msg
    msg = refusal(edited("table_clearing_hsr", lambda d: _cup(d, OBJECT_SIZE_MAX * 1.01)))
    assert msg is not None and "'cup'.size" in msg and "OBJECT_SIZE_MAX" in msg


def test_fixture_size_and_height_bounds():
    def huge(d):
        d["fixture"][1]["size"][0] = FIXTURE_SIZE_MAX * 1.5

    assert "FIXTURE_SIZE_MAX" in refusal(edited("sorting_pr2", huge))

    def tall(d):  # the far table grown upward past HEIGHT_MAX
        f = d["fixture"][1]
        f["size"][2] = HEIGHT_MAX
        f["pose"][2] = HEIGHT_MAX / 2 + 0.01

    assert "HEIGHT_MAX" in refusal(edited("sorting_pr2", tall))


def test_workspace_and_coordinate_bounds():
    def far(dist):
        def fn(d):  # the far table (nothing on it) moved off along +x from the base
            d["fixture"][1]["pose"][:2] = [d["robot"]["base"][0] + dist, d["robot"]["base"][1]]
            d["region"] = [r for r in d["region"] if r["on"] != d["fixture"][1]["name"]]
            d["goal"]["literals"] = d["goal"]["literals"][1:]
        return fn

    assert refusal(edited("sorting_pr2", far(WORKSPACE_RADIUS - 1))) is None
    msg = refusal(edited("sorting_pr2", far(WORKSPACE_RADIUS + 1)))
    assert "WORKSPACE_RADIUS" in msg and "'table_blue'.pose" in msg
    msg = refusal(edited("sorting_pr2", lambda d: d["robot"]["base"].__setitem__(0, -COORD_MAX * 2)))
    assert "[robot].base" in msg and "x = -2000" in msg and "COORD_MAX" in msg
    msg = refusal(edited("sorting_pr2", lambda d: d["robot"]["base"].__setitem__(2, ANGLE_MAX + 0.1)))
    assert "yaw" in msg and "ANGLE_MAX" in msg


def test_joint_values_keep_the_urdf_range_with_a_small_tolerance():
    lim = load_robot("hsr").limits
    i = lim.names.index("arm_lift_joint")
    hi = float(lim.upper[i])

    def lift(v):
        return edited("sorting_hsr", lambda d: d["robot"].update(joints={"arm_lift_joint": v}))

    scene = scene_from_dict(lift(hi + JOINT_TOLERANCE / 2), "t.toml")
    assert scene.robot.joints["arm_lift_joint"] == hi  # within the tolerance: held to the limit
    msg = refusal(lift(hi + 2 * JOINT_TOLERANCE))
    assert "[robot].joints.arm_lift_joint" in msg and f"[0, {hi:.4g}] m" in msg
    msg = refusal(edited("pick_place_pr2", lambda d: d["robot"]["joints"].update(r_forearm_roll_joint=40.0)))
    assert "continuous" in msg and "ANGLE_MAX" in msg


def test_robot_start_clear_of_every_fixture_footprint():
    # HSR: a disc of 0.215 m; table_clearing's table spans x in [-0.15, 0.55], y in [0.75, 1.25]
    def base_at(y):
        return edited("table_clearing_hsr", lambda d: d["robot"].update(base=[0.2, y, 0.0]))

    assert refusal(base_at(0.75 - 0.215 - 0.002)) is None  # 2 mm clear (PyBullet's margins make touching 1 mm deep)
    msg = refusal(base_at(0.75 - 0.2))
    assert "[robot].base" in msg and "starts inside fixture 'table'" in msg and "radius 0.215" in msg
    # PR2: a 0.67 m square, turned with the base; pick_place's table edge at y = -0.4
    def pr2_at(y, yaw):
        return edited("pick_place_pr2", lambda d: d["robot"].update(base=[0.0, y, yaw]))

    assert refusal(pr2_at(-0.4 - 0.335 - 0.002, 0.0)) is None
    assert "starts inside fixture" in refusal(pr2_at(-0.4 - 0.335, math.pi / 4))  # its corner reaches in


def test_fixtures_may_touch_but_not_interpenetrate():
    # table_clearing's upper step touches the cabinet's side (y = 0.1); moved 1 cm into it
    msg = refusal(edited("table_clearing_hsr", lambda d: d["fixture"][2]["pose"].__setitem__(1, 0.24)))
    assert "[[fixture]] 'step_upper'.pose: interpenetrates fixture 'cabinet'" in msg


def test_a_scene_without_a_goal_is_refused():
    msg = refusal(edited("tower_pr2", lambda d: d.pop("goal")))
    assert msg.startswith("t.toml: [goal]: missing")
    msg = refusal(edited("tower_pr2", lambda d: d["goal"].update(literals=[])))
    assert msg.startswith("t.toml: [goal].literals: empty")


def test_file_level_refusals(tmp_path):
    deep = tmp_path / "deep.toml"
    deep.write_text(dump_toml(raw("sorting_hsr")) + "x = " + "[" * 5000 + "]" * 5000 + "\n")
    with pytest.raises(SceneError, match=r"deep\.toml: \(toml\): .*nested too deep"):
        load_scene(deep)
    big = tmp_path / "big.toml"
    big.write_bytes(b"# " + b"x" * FILE_BYTES_MAX)
    with pytest.raises(SceneError, match=r"big\.toml: \(file\): larger than"):
        load_scene(big)
    with pytest.raises(SceneError, match=r"\(file\): cannot read"):
        load_scene(tmp_path)  # a folder


def test_huge_values_are_quoted_short():
    for value in ("a" * 10_000_000, 10**5000, [[[1]]] * 10_000, {"k" * 1000: "v" * 1000}):
        msg = refusal(edited("sorting_pr2", lambda d, v=value: d["fixture"][0].update(size=v)))
        assert "[[fixture]] 'table_mid'.size" in msg and len(msg) < 200, msg[:600]
    msg = refusal(edited("sorting_pr2", lambda d: d["fixture"][0].update(size=[[[[[[1]]]]]] * 10_000)))
    assert msg.startswith("t.toml: fixture[0].size[9999] ...: nested deeper than 8 levels") and len(msg) < 200


def test_a_message_stays_under_message_max_whatever_the_file_name_and_keys():
    data = edited("sorting_pr2", lambda d: d["scene"].update({f"{'k' * 200}{i}": 1 for i in range(50)}))
    with pytest.raises(SceneError) as info:
        scene_from_dict(data, "f" * 300 + ".toml")
    assert len(str(info.value)) <= MESSAGE_MAX and "unknown key(s)" in str(info.value)


values = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(), st.text(max_size=200)),
                      lambda inner: st.one_of(st.lists(inner, max_size=8),
                                              st.dictionaries(st.text(max_size=80), inner, max_size=8)),
                      max_leaves=60)


@settings(max_examples=150, deadline=None)
@given(values)
def test_quote_is_bounded_whatever_the_value(value):
    assert len(quote(value)) <= QUOTE_MAX + len(" (99999999 characters)")


# --------------------------------------------------------------------------- load-only fuzz
def assert_within_rules(scene) -> None:
    """A scene that loaded keeps every bound of rules.py."""
    assert scene.goal.literals
    bx, by, byaw = scene.robot.base
    assert abs(bx) <= COORD_MAX and abs(by) <= COORD_MAX and abs(byaw) <= ANGLE_MAX
    for item, size_max in [(f, FIXTURE_SIZE_MAX) for f in scene.fixtures] + [(o, OBJECT_SIZE_MAX)
                                                                             for o in scene.objects]:
        assert all(SIZE_MIN <= s <= size_max for s in item.size), item
        assert all(math.isfinite(v) for v in item.pose), item
        assert math.hypot(item.pose[0] - bx, item.pose[1] - by) <= WORKSPACE_RADIUS, item
        assert item.pose[2] + item.size[2] / 2 <= HEIGHT_MAX and abs(item.pose[3]) <= ANGLE_MAX, item
    lim = load_robot(scene.robot.name).limits
    for j, v in scene.robot.joints.items():
        i = lim.names.index(j)
        assert lim.lower[i] <= v <= lim.upper[i] or (math.isinf(lim.lower[i]) and abs(v) <= ANGLE_MAX), (j, v)


def test_fuzzed_scene_files_load_within_the_rules_or_fail_with_a_short_scene_error(tmp_path):
    sources = [(p.name, p.read_bytes()) for p in sorted(SCENES_DIR.glob("*.toml"))]
    loaded, refused, ops = 0, 0, set()
    for i, m in enumerate(mutants(sources, 400, seed=7)):
        path = tmp_path / f"m{i}.toml"
        path.write_bytes(m.data)
        ops.update(m.label.split(":")[1].split("+"))
        try:
            scene = load_scene(path)
        except SceneError as e:  # anything else fails the test
            refused += 1
            msg = str(e)
            assert msg.startswith(f"m{i}.toml: ") and e.where and e.detail, (m.label, msg[:300])
            assert len(msg) < MESSAGE_LIMIT, (m.label, msg[:600])
            continue
        loaded += 1
        assert_within_rules(scene)
    assert ops == set(OPERATORS)  # every operator was exercised
    assert loaded >= 10 and refused >= 300, (loaded, refused)
