"""GNPP drives the PR2's base (the paper's start-move / end-move): two arms on one base share it in the
graph-NLP (``SameBase``), and a task with a target beyond the arms' reach from the start plans, validated
by the replay."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.capabilities import beyond_reach, refuse
from rlgp_exec.planning.gnpp import GnppStatus, plan_gnpp
from rlgp_exec.planning.gnpp.geometry import MAX_TILT, FactorLib
from rlgp_exec.planning.gnpp.guess import TopIK, initial_guess
from rlgp_exec.planning.gnpp.pntc import add_flags, add_moves, factors_of, moving
from rlgp_exec.planning.symbolic import GroundAction, SymbolicError, ground_scene
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import Goal, load_scene
from rlgp_exec.scene.literals import parse_literal

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"


def _one_block():
    """sorting_pr2 with its blue block only: reachable from the start, its tray on a side table 2 m away."""
    sc = load_scene(SCENES / "sorting_pr2.toml")
    return dataclasses.replace(
        sc,
        fixtures=tuple(f for f in sc.fixtures if f.name != "table_green"),
        regions=tuple(r for r in sc.regions if r.name != "tray_green"),
        objects=tuple(o for o in sc.objects if o.name == "block_blue"),
        goal=Goal((parse_literal("(on block_blue tray_blue)"),)),
    )


@pytest.fixture(scope="module")
def pr2():
    return load_robot("pr2")


def test_the_pr2_base_moves_only_when_the_start_base_cannot_serve(pr2):
    """Out of reach from the start: both arms' variables carry the base, the second arm rides the first's;
    every object within reach (tower_pr2): the base stays fixed, the arms' variables are their joints."""
    scene = _one_block()
    assert beyond_reach(scene) and "tray_blue" in beyond_reach(scene)[0]
    lib = FactorLib(pr2, scene)
    assert lib.mobile and lib.riders == {lib.arms[1]: lib.base_arm}
    assert all(lib.dim("q", m) == 10 for m in lib.arms)
    assert [pr2.joint_names[i] for i in lib.arm_index(lib.arms[1])[:3]] == list(
        pr2.joint_names[i] for i in pr2.group("base"))
    fixed = FactorLib(pr2, load_scene(SCENES / "tower_pr2.toml"))
    assert not fixed.mobile and not fixed.riders and fixed.dim("q", "left_arm") == 7
    assert FactorLib(pr2, load_scene(SCENES / "tower_pr2.toml"), mobile=True).mobile  # asked for


def test_both_arms_wait_for_the_shared_base_and_samebase_ties_them(pr2):
    """The rider's pick is not applicable while the base moves; SameBase holds at every step after the
    start (RefQ pins both there), EqualBase on the moving arm only outside the moving states: no equality
    is repeated (a Newton-type solver does not tolerate redundant ones)."""
    scene = _one_block()
    lib = FactorLib(pr2, scene)
    mover, rider = lib.base_arm, lib.arms[1]
    task = add_flags(add_moves(ground_scene(scene, manipulators=list(lib.arms)), [mover], lib.riders))
    start, end = GroundAction.parse(f"(start-move {mover})"), GroundAction.parse(f"(end-move {mover})")
    with pytest.raises(SymbolicError):
        task.simulate([start, GroundAction.parse(f"(pick {rider} block_blue table_mid)")])
    acts = [GroundAction.parse(f"(pick {rider} block_blue table_mid)"), start, end,
            GroundAction.parse(f"(place {rider} block_blue tray_blue)")]
    states = task.simulate(acts)
    assert moving(mover) in states[2]
    graph = factors_of(states, lib.arms, ["block_blue"], [mover], lib.riders)
    same = sorted(f.times for f in graph if f.kind == "SameBase")
    assert same == [(t, t) for t in range(1, 5)]
    assert sorted(f.times for f in graph if f.kind == "EqualBase") == [(0, 1), (3, 4)]
    assert all(f.key[1] == mover for f in graph if f.kind == "EqualBase")
    # the initial guess keeps one base per state for both arms (as SameBase will)
    from rlgp_exec.planning.gnpp.graph import variables

    guess = initial_guess(lib, TopIK(lib), states, variables(graph))
    for t in range(len(states)):
        assert np.allclose(guess[_q(mover, t)][:3], guess[_q(rider, t)][:3])
    assert np.allclose(guess[_q(mover, 0)][:3], lib.q_nominal[:3])
    assert np.linalg.norm(guess[_q(mover, 4)][:2] - lib.q_nominal[:2]) > 1.0  # at the side table


def _q(arm: str, t: int):
    from rlgp_exec.planning.gnpp.pntc import Var

    return Var("q", arm, t)


def test_gnpp_drives_the_pr2_to_a_tray_beyond_reach_and_the_replay_validates_it(pr2):
    """The tray 2 m away: the plan moves the base (start-move / end-move), places there, and passes the
    PyBullet replay (collision checked, goal checked); every pick and place stands still (the yaw modulo
    a turn: the paths are wrapped, the replay interpolates the short way)."""
    scene = _one_block()
    refuse(scene, "gnpp_trn")  # accepted: GNPP drives the PR2's base
    res = plan_gnpp(scene, "gnpp_trn", timeout_s=200.0)  # a generous budget (not a timing assertion)
    assert res.status is GnppStatus.SOLVED, res.plan.reason
    plan = res.plan
    assert plan.validation is not None and plan.validation.collision_free and plan.validation.goal_met
    assert any(a.startswith("(end-move") for a in plan.actions)
    base = np.vstack([ph.path[:, :2] for ph in plan.phases])
    assert float(np.max(np.linalg.norm(base - base[0], axis=1))) > 1.0
    for k, a in enumerate(plan.actions):
        if a.split()[0][1:] in ("pick", "place", "stack"):
            path = plan.phases[k].path
            assert np.allclose(pr2.limits.difference(path[-1], path[0])[:3], 0.0, atol=1e-6)
    place = next(k for k, a in enumerate(plan.actions) if a.startswith("(place"))
    side_table = next(f for f in scene.fixtures if f.name == "table_blue")
    at = plan.phases[place].path[-1][:2]  # beside the side table (its centre 2.4 m from the start)
    assert np.linalg.norm(at - np.asarray(side_table.pose[:2])) < 1.5 < np.linalg.norm(at - base[0])


def test_a_driven_pr2_carries_at_its_side_clear_of_itself(pr2):
    """The start posture (the tuck) interlocks the arms a centimetre apart: an idle arm holding an object
    waits in ``carry_q`` instead, the tool below and outside its shoulder pointing down, each arm's posture
    clear of the other arm (tucked or carrying too) in PyBullet; robots whose arms do not share a driven
    base have none (the start posture serves)."""
    import pybullet as p

    from rlgp_exec.planning.gnpp.motion import carry_q
    from rlgp_exec.robot.pybullet_body import PyBulletRobot

    lib = FactorLib(pr2, _one_block())
    ik = TopIK(lib)
    carry = {arm: carry_q(lib, ik, arm) for arm in lib.arms}
    client = p.connect(p.DIRECT)
    try:
        robot = PyBulletRobot(pr2, client, collision_only=True)
        for arm, q in carry.items():
            assert q is not None
            T = lib.tool_T(arm, q)
            approach = T[:3, :3] @ np.asarray(pr2.manipulator(arm).approach, float)
            assert approach[2] <= -np.cos(MAX_TILT) + 1e-6  # pointing down (TopIK's tilt bound)
            shoulder = pr2.fk(lib.q_nominal, pr2.joint_names[pr2.group(pr2.manipulator(arm).group)[0]])
            assert T[2, 3] < shoulder[2, 3]
            assert not robot.in_collision(lib.full_q({arm: q}))
        assert not robot.in_collision(lib.full_q(carry))
    finally:
        p.disconnect(client)
    assert carry_q(FactorLib(pr2, load_scene(SCENES / "tower_pr2.toml")), ik, "left_arm") is None
    hsr = FactorLib(load_robot("hsr"), load_scene(SCENES / "sorting_hsr.toml"))
    assert carry_q(hsr, TopIK(hsr), hsr.arms[0]) is None


def test_a_seeded_pick_takes_the_base_tied_to_it_along(pr2):
    """``ik_seed`` on a bearing round the object moves the picking arm's base: the arm variables the subgraph
    ties to it (``EqualBase`` the step before, ``SameBase`` the other arm) start on that base too, not where
    the guess had them."""
    from rlgp_exec.planning.gnpp.graph import variables
    from rlgp_exec.planning.gnpp.guess import ik_seed

    scene = _one_block()
    lib = FactorLib(pr2, scene)
    ik = TopIK(lib)
    mover = lib.base_arm
    task = add_flags(add_moves(ground_scene(scene, manipulators=list(lib.arms)), [mover], lib.riders))
    acts = [GroundAction.parse(a) for a in (f"(start-move {mover})", f"(end-move {mover})",
                                            f"(pick {mover} block_blue table_mid)")]
    states = task.simulate(acts)
    graph = factors_of(states, lib.arms, ["block_blue"], [mover], lib.riders)
    guess = initial_guess(lib, ik, states, variables(graph))
    kin = next(f for f in graph if f.kind == "Kin")
    sub = [kin, *(f for f in graph if f.kind in ("EqualBase", "SameBase") and kin.vars[0] in f.vars)]
    tied = {v for f in sub for v in f.vars if v.kind == "q"}
    assert len(tied) == 3  # the pick's, the same arm's the step before, the other arm's
    for bearing in (1, 4):
        seeded = ik_seed(lib, ik, sub, guess, bearing)
        base = seeded[kin.vars[0]][:3]
        assert not np.allclose(base, guess[kin.vars[0]][:3])  # the bearing moved it
        for v in tied:
            assert np.allclose(seeded[v][:3], base), v
            assert np.allclose(seeded[v][3:], guess[v][3:]) or v == kin.vars[0]
