"""GNPP with drawers: the drawer actions' factors (the knob grasp, the base driven with the drawer, the
object in a drawer riding in its frame), their partial states for the learnt conflicts, and a drawer
task planned end to end and replayed (the articulated drive checked there)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.capabilities import refuse
from rlgp_exec.planning.gnpp import GnppStatus, plan_gnpp
from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.graph import to_forbidden
from rlgp_exec.planning.gnpp.pntc import add_flags, add_moves, factors_of
from rlgp_exec.planning.symbolic import GroundAction, ground_scene
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.literals import parse_literal

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"
KNOB_BASE = (0.45, -0.5, 0.6)  # [m, rad] an HSR base from which the arm reaches the cabinet's knob


def _trimmed(goal: list[str], base=KNOB_BASE):
    """table_clearing_hsr with the block alone, the robot in front of the drawer, ``goal``."""
    sc = load_scene(SCENES / "table_clearing_hsr.toml")
    return dataclasses.replace(
        sc,
        objects=tuple(o for o in sc.objects if o.name == "block"),
        robot=dataclasses.replace(sc.robot, base=base),
        goal=dataclasses.replace(sc.goal, literals=tuple(parse_literal(g) for g in goal)),
    )


@pytest.fixture(scope="module")
def hsr():
    return load_robot("hsr")


def _graph(scene, hsr, plan: list[str]):
    lib = FactorLib(hsr, scene)
    task = add_flags(add_moves(ground_scene(scene, manipulators=list(lib.arms)), lib.arms))
    states = task.simulate([GroundAction.parse(a) for a in plan])
    return lib, states, factors_of(states, lib.arms, [o.name for o in scene.objects], lib.arms)


def test_the_drawer_actions_map_to_their_factors(hsr):
    scene = _trimmed(["(in block cabinet)", "(closed cabinet)"])
    plan = ["(take_knob arm cabinet)", "(open_drawer arm cabinet)", "(pick arm block table)",
            "(drop arm block cabinet)", "(take_knob arm cabinet)", "(close_drawer arm cabinet)"]
    _, _, graph = _graph(scene, hsr, plan)
    keys = {f.key for f in graph}
    assert {("Knob", "arm", "cabinet", "closed"), ("Knob", "arm", "cabinet", "open"),
            ("Drive", "arm", "cabinet", "open"), ("Drive", "arm", "cabinet", "close"),
            ("Drop", "block", "arm", "cabinet"), ("InDrawer", "block", "cabinet")} <= keys
    # the base follows the drawer: no EqualBase across a drive (open: 1 -> 2, close: 5 -> 6)
    base_steps = {f.times for f in graph if f.kind == "EqualBase"}
    assert (1, 2) not in base_steps and (5, 6) not in base_steps and (0, 1) in base_steps
    # the dropped block rides in the drawer's frame: one pose, Equal across the close (the drawer moves it)
    assert any(f.kind == "Equal" and f.times == (5, 6) and f.vars[0].owner == "block" for f in graph)
    # the collision factors name the drawers' openings; the hand on the knob (or just off it) leaves that drawer out
    tags = {f.vars[0].t: f.key[2] for f in graph if f.kind == "ColFix"}
    assert tags[1] == "cabinet:closed+knob" and tags[2] == "cabinet:open+knob" and tags[3] == "cabinet:open"
    # its arm factor in the open drawer: the block's pose is in the drawer's frame there
    assert ("ColAO", "arm", "block", "cabinet") in keys
    # a knob conflict traces back to the logic: the partial states name the opening and the grasp of the knob
    knob = next(f for f in graph if f.kind == "Knob" and f.key[3] == "closed")
    seq = to_forbidden([knob])
    assert ("holding-knob", "arm", "cabinet") in seq.states[-1].pos and ("closed", "cabinet") in seq.states[-1].pos


def test_the_drive_moves_the_base_along_the_axis_and_the_knob_moves_with_it(hsr):
    scene = _trimmed(["(open cabinet)"])
    lib = FactorLib(hsr, scene)
    v = lib.drawers["cabinet"]
    ok, q = lib.knob_ik.solve("arm", "cabinet", frozenset({("closed", "cabinet")}), lib.home_q("arm"))
    assert ok
    knob = lib.factor(("Knob", "arm", "cabinet", "closed"))
    g = np.asarray(knob.fn(q)).ravel()
    assert np.all(g >= knob.lower - 1e-4) and np.all(g <= knob.upper + 1e-4)
    q2 = q.copy()
    q2[:2] += v.travel * v.axis_world[:2]
    drive = lib.factor(("Drive", "arm", "cabinet", "open"))
    assert np.allclose(np.asarray(drive.fn(q, q2)).ravel(), 0.0, atol=1e-9)
    assert not np.allclose(np.asarray(drive.fn(q, q)).ravel(), 0.0, atol=1e-3)  # a drive that does not move
    # ... and the hand where the base took it is on the knob of the open drawer
    opened = lib.factor(("Knob", "arm", "cabinet", "open"))
    g2 = np.asarray(opened.fn(q2)).ravel()
    assert np.all(g2 >= opened.lower - 1e-4) and np.all(g2 <= opened.upper + 1e-4)
    # an object in the drawer: its drawer-frame pose is where it is in the world at either opening
    w = np.array([0.0, 0.0, 0.0, 0.0])
    out_by = lib.in_world("cabinet", v.travel, w)[:3] - lib.in_world("cabinet", 0.0, w)[:3]
    assert np.allclose(out_by, v.travel * v.axis_world)


def test_gnpp_opens_a_drawer_end_to_end_and_the_replay_checks_it():
    scene = _trimmed(["(open cabinet)"])
    refuse(scene, "gnpp_trn")  # accepted
    res = plan_gnpp(scene, timeout_s=60.0)
    assert res.status is GnppStatus.SOLVED, res.plan.reason
    assert res.plan.actions == ("(take_knob cabinet)", "(open_drawer cabinet)")  # one arm: not named
    v = res.plan.validation
    assert v is not None and v.collision_free and v.goal_met
    assert v.final_openings["cabinet"] == pytest.approx(0.3, abs=0.01)
    assert any(ph.drives_drawer for ph in res.plan.phases)


def test_a_drawer_the_arm_cannot_reach_is_a_learnt_conflict_on_the_knob():
    """From a base too far from the knob the first plan is refuted by a conflict with the Knob factor, which
    the logic learns: the next plan drives the base (start-move / end-move) before it takes the knob."""
    scene = _trimmed(["(open cabinet)"], base=(-0.8, -0.5, 0.0))
    res = plan_gnpp(scene, timeout_s=60.0)
    assert res.status is GnppStatus.SOLVED, res.plan.reason
    assert any(f.kind == "Knob" for c in res.conflict_factors for f in c.factors)
    assert res.plan.actions[:3] == ("(start-move)", "(end-move)", "(take_knob cabinet)")
    assert res.plan.validation is not None and res.plan.validation.ok
