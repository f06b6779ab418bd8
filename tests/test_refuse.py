"""Tasks that cannot be done are refused before any search, by name: what the planner cannot express
(``planning.capabilities``), what no hand can hold (``feasibility.physical_refusals``), what no stack can
be (``scene.validate.validate_goal_stacks``, at load)."""

from __future__ import annotations

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from rlgp_exec.errors import RlgpError, SceneError
from rlgp_exec.planning import capabilities
from rlgp_exec.planning.capabilities import CAPABILITIES, TaskRefusedError, needed_actions, refuse
from rlgp_exec.planning.feasibility import physical_refusals
from rlgp_exec.planning.gripper_limits import gripper_limits, min_graspable_height
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.generate import sorting_scene
from rlgp_exec.scene.types import Goal

ROOT = Path(__file__).resolve().parents[1]
SCENES = ROOT / "sim" / "scenes"
SHIPPED = sorted(SCENES.glob("*.toml"))


def _resized(scene, name: str, size):
    return dataclasses.replace(scene, objects=tuple(
        dataclasses.replace(o, size=tuple(size), pose=(*o.pose[:2], o.pose[2] - (o.size[2] - size[2]) / 2, o.pose[3]))
        if o.name == name else o for o in scene.objects))


def _without(scene, name: str):
    """The scene with the object and every goal literal naming it dropped."""
    lits = tuple(lit for lit in scene.goal.literals if name not in lit.args)
    return dataclasses.replace(scene, objects=tuple(o for o in scene.objects if o.name != name), goal=Goal(lits))


@pytest.mark.parametrize("path", SHIPPED, ids=[p.stem for p in SHIPPED])
def test_shipped_scenes_are_accepted_by_a_planner_that_can_express_them(path):
    scene = load_scene(path)
    assert physical_refusals(scene) == []
    accepted = []
    for planner in ("rlgp", "gnpp_trn"):
        try:
            refuse(scene, planner)
            accepted.append(planner)
        except TaskRefusedError as e:
            assert "--planner" in str(e) or "drives the base" in str(e), e
    assert accepted, path.name


@pytest.mark.parametrize(("robot", "n", "seed"), [("hsr", 2, 0), ("hsr", 6, 1), ("pr2", 3, 0), ("pr2", 12, 2)])
def test_generated_sorting_scenes_are_accepted_by_rlgp(robot, n, seed):
    scene = sorting_scene(robot, n, seed)
    assert physical_refusals(scene) == []
    refuse(scene, "rlgp")


def test_the_table_matches_what_the_planners_realise():
    """The capabilities table is the one place a new action kind is declared: it must agree with the
    geometric layers it stands for."""
    from rlgp_exec.planning.gnpp.planner import GEOMETRIC
    from rlgp_exec.planning.gnpp.pntc import MOVES
    from rlgp_exec.planning.rlgp import GEOMETRIC_ACTIONS

    assert CAPABILITIES["rlgp"].actions == frozenset(GEOMETRIC_ACTIONS)
    assert CAPABILITIES["gnpp_trn"].actions == frozenset(GEOMETRIC) - frozenset(MOVES)


def test_a_drawer_task_is_accepted_by_both_planners():
    scene = load_scene(SCENES / "table_clearing_hsr.toml")
    assert {"drop", "take_knob", "open_drawer"} <= set(needed_actions(scene))  # it starts closed
    for planner in ("rlgp", "gnpp_trn", "gnpp_trng"):
        assert {"drop", "take_knob", "open_drawer", "close_drawer"} <= CAPABILITIES[planner].actions
        refuse(scene, planner)


def test_a_drawer_kind_missing_from_gnpp_is_refused_naming_it_and_who_has_it(monkeypatch):
    """With the drawer kinds taken out of GNPP's entry, table clearing is refused at once, naming R-LGP."""
    from rlgp_exec.planning import capabilities

    gnpp = CAPABILITIES["gnpp_trn"]
    without = gnpp._replace(actions=gnpp.actions - {"drop", "take_knob", "open_drawer", "close_drawer"})
    for name, cap in CAPABILITIES.items():
        if cap is gnpp:  # every GNPP variant shares the entry
            monkeypatch.setitem(capabilities.CAPABILITIES, name, without)
    with pytest.raises(TaskRefusedError, match=r"gnpp_trn: no drawer actions .*use --planner rlgp"):
        refuse(load_scene(SCENES / "table_clearing_hsr.toml"), "gnpp_trn")


@pytest.mark.parametrize("name", ["tower_pr2", "hanoi_pr2"])
def test_stacking_tasks_need_the_stack_action_which_both_planners_have(name):
    scene = load_scene(SCENES / f"{name}.toml")
    assert "stack" in needed_actions(scene)
    for planner in ("rlgp", "gnpp_trn"):
        assert "stack" in CAPABILITIES[planner].actions
    refuse(scene, "rlgp")  # accepted: R-LGP drives the base and stacks


def test_a_kind_missing_from_a_planner_is_refused_naming_it_and_who_has_it(monkeypatch):
    """With stack taken out of R-LGP's entry, a tower is refused at once, naming GNPP (the table is what decides)."""
    from rlgp_exec.planning import capabilities
    from rlgp_exec.planning.rlgp import plan_scene

    without = CAPABILITIES["rlgp"]._replace(actions=CAPABILITIES["rlgp"].actions - {"stack"})
    monkeypatch.setitem(capabilities.CAPABILITIES, "rlgp", without)
    with pytest.raises(TaskRefusedError, match=r"rlgp: no stack action \(stack for \(on .*use --planner gnpp"):
        plan_scene(load_scene(SCENES / "tower_pr2.toml"))


def test_a_planner_that_keeps_the_pr2_base_refuses_objects_beyond_the_arms_reach(monkeypatch):
    """Both planners drive the PR2's base, so sorting_pr2 is accepted by both; a planner entry that keeps
    the base at its start refuses it, naming what lies beyond the reach bound and who drives the base."""
    from rlgp_exec.planning import capabilities

    scene = load_scene(SCENES / "sorting_pr2.toml")
    assert "pr2" in CAPABILITIES["gnpp_trn"].drives_base
    refuse(scene, "gnpp_trn")
    refuse(scene, "rlgp")
    fixed = CAPABILITIES["gnpp_trn"]._replace(drives_base=frozenset({"hsr"}))
    monkeypatch.setitem(capabilities.CAPABILITIES, "gnpp_trn", fixed)
    with pytest.raises(TaskRefusedError) as e:
        refuse(scene, "gnpp_trn")
    assert "block_green is" in str(e.value) and "drive the base: use --planner" in str(e.value)
    refuse(load_scene(SCENES / "pick_place_pr2.toml"), "gnpp_trn")  # all within reach: accepted


def test_gripper_limits_come_from_the_robots_own_fingers():
    hsr, pr2 = gripper_limits("hsr"), gripper_limits("pr2")
    assert 0.05 < pr2.open_width_m < hsr.open_width_m < 0.3  # the HSR's open hand spans much wider
    shipped = [o for p in SHIPPED for o in load_scene(p).objects if load_scene(p).robot.name == "pr2"]
    assert max(min(o.size[:2]) for o in shipped) <= pr2.max_width_m
    assert 0.0 < min_graspable_height(pr2) <= min(o.size[2] for o in shipped)


@pytest.mark.parametrize("planner", ["rlgp", "gnpp_trn"])
def test_an_object_wider_than_the_open_gripper_is_refused_with_the_numbers(planner):
    scene = load_scene(SCENES / "pick_place_pr2.toml")
    victim = next(lit.args[0] for lit in scene.goal.literals if lit.predicate == "on")
    wide = _resized(scene, victim, (0.10, 0.12, scene.object(victim).size[2]))
    with pytest.raises(TaskRefusedError) as e:
        refuse(wide, planner)
    msg = str(e.value)
    assert f"{victim} is wider than the pr2's open gripper: its narrower side 0.100 m" in msg
    assert f"at most {gripper_limits('pr2').max_width_m:.3f} m" in msg


def test_an_object_shorter_than_the_grasp_needs_is_refused():
    scene = load_scene(SCENES / "pick_place_pr2.toml")
    victim = next(lit.args[0] for lit in scene.goal.literals if lit.predicate == "on")
    low = min_graspable_height(gripper_limits("pr2"))
    flat = _resized(scene, victim, (*scene.object(victim).size[:2], low * 0.8))
    with pytest.raises(TaskRefusedError, match=f"{victim} is shorter than the pr2's grasp needs"):
        refuse(flat, "rlgp")
    refuse(_resized(scene, victim, (*scene.object(victim).size[:2], low * 1.05)), "rlgp")


def test_an_object_the_goal_does_not_move_is_not_refused_for_its_size():
    scene = load_scene(SCENES / "pick_place_pr2.toml")
    kept, *rest = [lit for lit in scene.goal.literals if lit.predicate == "on"]
    assert rest, "pick_place_pr2 moves more than one object"
    one = dataclasses.replace(scene, goal=Goal((kept,)))
    wide = _resized(one, rest[0].args[0], (0.09, 0.09, scene.object(rest[0].args[0]).size[2]))
    refuse(wide, "rlgp")  # the goal leaves it where it stands
    with pytest.raises(TaskRefusedError, match=rest[0].args[0]):
        refuse(dataclasses.replace(wide, goal=scene.goal), "rlgp")


@pytest.mark.parametrize("rule", ["wide", "short", "tiny"])
def test_dropping_the_offending_object_makes_the_scene_accepted(rule):
    """Property: for every goal object of the shipped PR2 and HSR sorting tasks made impossible by one rule,
    the scene is refused naming it, and the same scene without that object is accepted."""
    for path in (SCENES / "sorting_hsr.toml", SCENES / "pick_place_pr2.toml"):
        scene = load_scene(path)
        limits = gripper_limits(scene.robot.name)
        for lit in scene.goal.literals:
            if lit.predicate != "on":
                continue
            o = scene.object(lit.args[0])
            size = {"wide": (limits.max_width_m + 0.01, 0.3, o.size[2]),
                    "short": (*o.size[:2], 0.6 * min_graspable_height(limits) or 0.004),
                    "tiny": (0.004, o.size[1], o.size[2])}[rule]
            bad = _resized(scene, o.name, size)
            with pytest.raises(TaskRefusedError, match=o.name):
                refuse(bad, "rlgp")
            refuse(_without(bad, o.name), "rlgp")


def _stack_scene(sizes: dict[str, float], goal: list[str]):
    """tower_pr2 with its blocks' footprints set (square, [m]) and the goal replaced, through the loader."""
    import tomllib

    from rlgp_exec.scene import scene_from_dict

    data = tomllib.loads((SCENES / "tower_pr2.toml").read_text())
    for o in data["object"]:
        if o["name"] in sizes:
            o["size"] = [sizes[o["name"]], sizes[o["name"]], o["size"][2]]
    data["goal"] = {"literals": goal}
    return scene_from_dict(data, "stack.toml")


def test_a_footprint_that_cannot_carry_another_is_refused_at_load():
    names = [o.name for o in load_scene(SCENES / "tower_pr2.toml").objects][:3]
    a, b, c = names
    with pytest.raises(SceneError, match=rf"\(on {a} {b}\): {b}'s footprint 0.04 x 0.04 m cannot carry {a}'s "
                                          r"0.05 x 0.05 m \(stacking rule"):
        _stack_scene({a: 0.05, b: 0.04}, [f"(on {a} {b})"])
    _stack_scene({a: 0.04, b: 0.05}, [f"(on {a} {b})"])  # smaller on larger: fine
    with pytest.raises(SceneError, match="one object stacks on another at most"):
        _stack_scene({}, [f"(on {a} {c})", f"(on {b} {c})"])
    with pytest.raises(SceneError, match=r"puts .* on itself"):
        _stack_scene({}, [f"(on {a} {b})", f"(on {b} {a})"])
    with pytest.raises(SceneError, match="an object rests on one support"):
        _stack_scene({}, [f"(on {a} {b})", f"(on {a} {c})"])


def test_gnpp_too_wide_does_not_call_a_narrow_object_wider():
    from rlgp_exec.planning.gnpp.geometry import FactorLib
    from rlgp_exec.robot import load_robot

    scene = load_scene(SCENES / "tower_pr2.toml")
    name = scene.objects[0].name
    narrow = _resized(scene, name, (0.02, 0.02, scene.object(name).size[2]))
    lib = FactorLib(load_robot("pr2"), narrow)
    assert lib.too_wide() == {} and lib.grasp_offset_max(name) == 0.0


def _gnpp_keeping_the_pr2_base(monkeypatch) -> None:
    fixed = CAPABILITIES["gnpp_trn"]._replace(drives_base=frozenset({"hsr"}))
    monkeypatch.setitem(capabilities.CAPABILITIES, "gnpp_trn", fixed)


def test_cli_plan_exits_2_with_the_refusal(monkeypatch):
    from rlgp_exec.cli import main

    _gnpp_keeping_the_pr2_base(monkeypatch)
    assert main(["plan", str(SCENES / "sorting_pr2.toml"), "--planner", "gnpp"]) == 2


_RSS_CHILD = """
import json, resource, sys
from rlgp_exec.planning.capabilities import TaskRefusedError
from rlgp_exec.planning.rlgp import plan_scene
from rlgp_exec.scene import scene_from_dict
scene = scene_from_dict(json.loads(sys.argv[1]), "memory.toml")
try:
    plan = plan_scene(scene, time_budget_s=float(sys.argv[2]), memory_cap_bytes=int(sys.argv[3]))
    outcome = "planned" if plan.success else "failed: " + plan.reason[:80]
except TaskRefusedError as e:
    outcome = "refused: " + str(e)[:80]
print(json.dumps({"outcome": outcome, "peak_rss": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024}))
"""
MEMORY_CAP = 1024 * 2**20  # [B] the planners' growth cap in this test
BASELINE = 700 * 2**20  # [B] the interpreter with the planners imported (about 450 MB here) and slack


def _peak_rss(data: dict, budget_s: float) -> dict:
    out = subprocess.run([sys.executable, "-c", _RSS_CHILD, json.dumps(data), str(budget_s), str(MEMORY_CAP)],
                         capture_output=True, text=True, cwd=ROOT, timeout=600,
                         env={"PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1", "PATH": "/usr/bin:/bin"})
    assert out.returncode == 0, out.stderr[-2000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


def _scene_dict(scene) -> dict:
    from rlgp_exec.scene.serialize import scene_to_dict

    return scene_to_dict(scene)


def test_memory_stays_bounded_on_degenerate_sizes():
    """A 1-micron object is refused by the loader's SIZE_MIN; objects at SIZE_MIN are refused (too short)
    or planned within the memory cap."""
    scene = load_scene(SCENES / "sorting_hsr.toml")
    data = _scene_dict(scene)
    data["object"][0]["size"] = [1e-6, 1e-6, 1e-6]
    with pytest.raises(SceneError, match="SIZE_MIN"):
        from rlgp_exec.scene import scene_from_dict

        scene_from_dict(data, "micron.toml")
    for size in ([0.005, 0.005, 0.005], [0.005, 0.005, 0.08]):
        data = _scene_dict(_resized(scene, scene.objects[0].name, size))
        data["object"][0].pop("tag", None)  # no tag fits on a 5 mm top
        res = _peak_rss(data, 10.0)
        assert res["peak_rss"] < BASELINE + MEMORY_CAP, res
        if size[2] < min_graspable_height(gripper_limits("hsr")):
            assert res["outcome"].startswith("refused"), res


def test_memory_stays_bounded_on_fifty_objects():
    """Fifty blocks (eight of them goal objects) on the sorting table: planned, failed or out of budget, the
    process stays within the cap."""
    base = sorting_scene("pr2", 8, 0)
    data = _scene_dict(base)
    table = next(f for f in data["fixture"] if f["name"] == base.object(base.objects[0].name).support)
    z = base.objects[0].pose[2] - base.objects[0].size[2] / 2 + 0.04  # an extra block's centre on the table
    k = 0
    while len(data["object"]) < 50:
        x = table["pose"][0] - table["size"][0] / 2 + 0.05 + 0.08 * (k % 14)
        y = table["pose"][1] + table["size"][1] / 2 - 0.05 - 0.08 * (k // 14)
        k += 1
        probe = dict(data, object=[*data["object"], {"name": f"extra_{k}", "shape": "box",
                                                     "size": [0.04, 0.04, 0.08], "pose": [x, y, z, 0.0]}])
        try:
            from rlgp_exec.scene import scene_from_dict

            scene_from_dict(probe, "fifty.toml")
        except SceneError:
            continue
        data = probe
        assert k < 200, "no room for 50 objects on the sorting table"
    res = _peak_rss(data, 20.0)
    assert res["peak_rss"] < BASELINE + MEMORY_CAP, res


def test_a_refusal_is_a_scene_error_naming_the_file_and_the_table(monkeypatch):
    _gnpp_keeping_the_pr2_base(monkeypatch)
    with pytest.raises(SceneError) as e:
        refuse(load_scene(SCENES / "sorting_pr2.toml"), "gnpp_trn")
    assert (e.value.source, e.value.where) == ("sorting_pr2.toml", "[robot].base")
    assert e.value.detail.startswith("gnpp_trn: keeps the pr2's base at its start")
    with pytest.raises(RlgpError, match="no capability entry for planner 'nope'; valid: "):
        refuse(load_scene(SCENES / "tower_pr2.toml"), "nope")
