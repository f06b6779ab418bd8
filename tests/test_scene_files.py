"""Scene files: the shipped ones are valid, bad ones fail with file/table/field, fuzzing raises only SceneError."""

from __future__ import annotations

import copy
import tomllib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rlgp_exec.errors import SceneError
from rlgp_exec.scene import cabinet_geometry, load_scene, randomize, scene_from_dict, scene_hash
from rlgp_exec.scene.geometry import boxes_overlap, object_box, support_surfaces
from rlgp_exec.scene.validate import _static_boxes

SCENES_DIR = Path(__file__).resolve().parents[1] / "sim" / "scenes"
SCENE_FILES = sorted(SCENES_DIR.glob("*.toml"))


def raw(name: str) -> dict:
    return tomllib.loads((SCENES_DIR / f"{name}.toml").read_text())


def assert_valid_placement(scene) -> None:
    statics = _static_boxes(scene)
    surfaces = {s.name: s for s in support_surfaces(scene)}
    boxes = [object_box(o) for o in scene.objects]
    for o, b in zip(scene.objects, boxes, strict=True):
        surf = surfaces[o.support]
        assert abs(o.pose[2] - o.size[2] / 2 - surf.z) < 1e-6, o.name
        assert surf.contains(np.asarray(o.pose[:2])), o.name
        assert not any(boxes_overlap(b, s) for s in statics), o.name
    for i in range(len(boxes)):
        for j in range(i):
            assert not boxes_overlap(boxes[i], boxes[j]), (scene.objects[i].name, scene.objects[j].name)


@pytest.mark.parametrize("path", SCENE_FILES, ids=[p.stem for p in SCENE_FILES])
def test_shipped_scene_loads_and_randomises_validly(path):
    scene = load_scene(path)
    assert scene.name == path.stem and scene.source == path.name
    assert scene.goal.literals
    assert_valid_placement(scene)
    seen = set()
    for seed in range(20):
        s = randomize(scene, seed)
        assert_valid_placement(s)
        assert randomize(scene, seed) == s  # reproducible per seed
        seen.add(tuple(o.pose for o in s.objects))
    if any(o.random for o in scene.objects):
        assert len(seen) == 20  # seeds differ


def test_randomised_objects_stay_inside_their_ranges():
    scene = load_scene(SCENES_DIR / "sorting_pr2.toml")
    table = scene.fixture("table_mid")
    for seed in range(20):
        for o in randomize(scene, seed).objects:
            local = np.linalg.inv(table.T) @ o.T
            assert o.random.x[0] <= local[0, 3] <= o.random.x[1]
            assert o.random.y[0] <= local[1, 3] <= o.random.y[1]


def test_scene_hash_ignores_objects_but_sees_fixtures():
    scene = load_scene(SCENES_DIR / "sorting_pr2.toml")
    assert scene_hash(randomize(scene, 3)) == scene_hash(scene)
    data = raw("sorting_pr2")
    data["fixture"][0]["pose"][0] += 0.01
    for o in data["object"]:  # they stand on it: moved with it
        o["pose"][0] += 0.01
    assert scene_hash(scene_from_dict(data, "moved.toml")) != scene_hash(scene)


def test_cabinet_geometry_is_consistent():
    scene = load_scene(SCENES_DIR / "table_clearing_hsr.toml")
    g = cabinet_geometry(scene.fixture("cabinet"))
    # the closed drawer's usable volume lies inside the carcass
    carcass_T = g.T_world_cabinet
    inner_world = g.T_world_drawer_closed @ g.inner_box.T
    local = np.linalg.inv(carcass_T) @ inner_world
    half_c = np.asarray(scene.fixture("cabinet").size) / 2
    half_i = np.asarray(g.inner_box.size) / 2
    assert np.all(np.abs(local[:3, 3]) + half_i <= half_c + 1e-9)
    # the knob sits on the drawer front's outer face, at knob_height
    front = next(b for b in g.drawer if b.name.endswith("drawer.front"))
    knob = g.drawer[-1]
    assert knob.T[0, 3] - knob.size[0] / 2 == pytest.approx(front.T[0, 3] + front.size[0] / 2)
    assert (g.T_world_drawer_closed @ g.T_drawer_knob)[2, 3] == pytest.approx(0.38)
    # panels touch but do not interpenetrate; the drawer clears the carcass
    parts = list(g.carcass) + [type(b)(b.name, b.size, g.T_world_drawer_closed @ b.T, b.color) for b in g.drawer]
    for i in range(len(parts)):
        for j in range(i):
            assert not boxes_overlap(parts[i], parts[j]), (parts[i].name, parts[j].name)
    # the drawer opens toward the cabinet's front (-x in the world for yaw = pi)
    assert np.allclose(g.axis_world, [-1, 0, 0], atol=1e-6)


# --------------------------------------------------------------------------- bad files
def mutate(name: str, fn) -> dict:
    data = copy.deepcopy(raw(name))
    fn(data)
    return data


BAD = [
    ("unknown top-level key", lambda d: d.update(extras={}), "(top level)", "extras"),
    ("unknown key in a table", lambda d: d["fixture"][0].update(colour="red"), "[[fixture]] #1", "colour"),
    ("wrong type", lambda d: d["fixture"][0].update(size="big"), "[[fixture]] 'table_mid'.size", "expected 3"),
    ("negative size", lambda d: d["object"][0].update(size=[0.05, -1.0, 0.1]), "'block_blue'.size", "positive"),
    ("unknown robot", lambda d: d["scene"].update(robot="nao"), "[scene].robot", "'pr2', 'hsr'"),
    ("unknown colour", lambda d: d["object"][0].update(color="teal"), "'block_blue'.color", "valid"),
    ("nan pose", lambda d: d["object"][0].update(pose=[0.0, 0.0, float("nan"), 0.0]), "'block_blue'.pose", "number"),
    ("floating object", lambda d: d["object"][0]["pose"].__setitem__(2, 1.2), "'block_blue'.pose", "float"),
    ("sunk object", lambda d: d["object"][0]["pose"].__setitem__(2, 0.70), "'block_blue'.pose",
     "sunk into 'table_mid'"),
    ("goal names an unknown object", lambda d: d["goal"].update(literals=["(on ghost tray_blue)"]),
     "[goal].literals[0]", "unknown object 'ghost'"),
    ("goal with unknown predicate", lambda d: d["goal"].update(literals=["(near block_blue tray_blue)"]),
     "[goal].literals[0]", "valid"),
    ("goal with wrong arity", lambda d: d["goal"].update(literals=["(on block_blue)"]), "[goal].literals[0]", "2"),
    ("duplicate names", lambda d: d["object"][1].update(name="block_blue"), "'block_blue'.name", "duplicate"),
    ("region off its fixture", lambda d: d["region"][0].update(offset=[0.5, 0.0]), "'tray_blue'.size", "hangs off"),
    ("region on an unknown fixture", lambda d: d["region"][0].update(on="shelf"), "'tray_blue'.on", "valid"),
    ("interpenetrating objects", lambda d: d["object"][1].update(pose=list(d["object"][0]["pose"])),
     "'block_green'.pose", "interpenetrates"),
    ("empty random range", lambda d: d["object"][0]["random"].update(x=[0.5, -0.5]), "'block_blue'.random.x", "empty"),
    ("random range off the table", lambda d: d["object"][0]["random"].update(x=[-2.0, 2.0]),
     "'block_blue'.random.x", "off"),
    ("unknown joint override", lambda d: d["robot"].update(joints={"elbow": 1.0}), "[robot].joints.elbow", "valid"),
]


@pytest.mark.parametrize(("case", "fn", "where", "text"), BAD, ids=[b[0] for b in BAD])
def test_bad_scene_fails_naming_file_table_and_field(case, fn, where, text):
    with pytest.raises(SceneError) as info:
        scene_from_dict(mutate("sorting_pr2", fn), "sorting_pr2.toml")
    msg = str(info.value)
    assert msg.startswith("sorting_pr2.toml: "), msg
    assert where in msg and text in msg, msg


def test_unreadable_and_non_toml_files(tmp_path):
    with pytest.raises(SceneError, match=r"missing\.toml"):
        load_scene(tmp_path / "missing.toml")
    bad = tmp_path / "broken.toml"
    bad.write_text("[scene\nname = 1")
    with pytest.raises(SceneError, match=r"broken.toml: \(toml\)"):
        load_scene(bad)


def test_drawer_that_does_not_fit_is_rejected():
    def fn(d):
        d["fixture"][1]["drawer"]["knob_height"] = 0.05

    with pytest.raises(SceneError, match=r"'cabinet'\.drawer\.knob_height"):
        scene_from_dict(mutate("table_clearing_hsr", fn), "t.toml")


# --------------------------------------------------------------------------- fuzzing
scalars = st.one_of(st.none(), st.booleans(), st.integers(-5, 5), st.floats(allow_nan=True, allow_infinity=True),
                    st.text(max_size=6), st.sampled_from(["box", "pr2", "hsr", "grey", "table_mid", "(on a b)"]))
values = st.recursive(scalars, lambda inner: st.one_of(st.lists(inner, max_size=4),
                                                       st.dictionaries(st.text(max_size=6), inner, max_size=4)),
                      max_leaves=12)
KEYS = ["scene", "robot", "fixture", "object", "region", "goal", "name", "size", "pose", "base", "literals",
        "drawer", "random", "tag", "on", "offset", "color", "kind", "shape", "joints"]


@st.composite
def mutated_scene(draw):
    data = copy.deepcopy(raw(draw(st.sampled_from(["sorting_pr2", "table_clearing_hsr", "hanoi_pr2"]))))
    for _ in range(draw(st.integers(1, 4))):
        # walk to a random table and replace or add a key with a random value
        node = data
        for _depth in range(draw(st.integers(0, 3))):
            children = [v for v in (node.values() if isinstance(node, dict) else node) if isinstance(v, (dict, list))]
            if not children:
                break
            node = draw(st.sampled_from(children))
        key = draw(st.sampled_from(KEYS))
        if isinstance(node, dict):
            node[key] = draw(values)
        elif isinstance(node, list) and node:
            node[draw(st.integers(0, len(node) - 1))] = draw(values)
    return data


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(mutated_scene())
def test_fuzzed_scene_dicts_raise_only_scene_error(data):
    try:
        scene_from_dict(data, "fuzz.toml")
    except SceneError as e:
        assert str(e).startswith("fuzz.toml: ")


@settings(max_examples=200, deadline=None)
@given(values)
def test_arbitrary_values_raise_only_scene_error(data):
    with pytest.raises(SceneError):
        scene_from_dict(data, "fuzz.toml")
