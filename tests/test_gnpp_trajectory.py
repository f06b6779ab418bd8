"""GNPP's trajectory stage (``planning.gnpp.trajectory``): each arm's moves between its keyframes as 20
optimised waypoints, through the path NLP of R-LGP's level 3 in its ``strict`` form."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.gnpp import trajectory
from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.planner import GnppStatus, plan_gnpp
from rlgp_exec.planning.nlp import path as level3
from rlgp_exec.reach.ik import arm_spheres
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.geometry import Box

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"


def _tower2():
    sc = load_scene(SCENES / "tower_pr2.toml")
    sc = dataclasses.replace(sc, objects=tuple(o for o in sc.objects if o.name in ("b1", "b2")))
    from rlgp_exec.scene.types import Literal

    goal = (Literal("on", ("b1", "goal_region")), Literal("on", ("b2", "b1")))
    return dataclasses.replace(sc, goal=dataclasses.replace(sc.goal, literals=goal))


def _plan(monkeypatch, tamper=None):
    """The two-block tower planned by gnpp_trn; returns (result, [(phases in, transits, phases out)])."""
    calls = []
    real = trajectory.Trajectories.optimise

    def spy(self, phases, transits):
        out, originals = real(self, phases, transits)
        if tamper is not None:
            out = tamper(out, transits)
        calls.append((phases, transits, out))
        return out, originals

    monkeypatch.setattr(trajectory.Trajectories, "optimise", spy)
    return plan_gnpp(_tower2(), "gnpp_trn", timeout_s=90.0), calls


def test_each_move_becomes_20_waypoints_between_the_same_ends_and_the_plan_replays(monkeypatch):
    res, calls = _plan(monkeypatch)
    assert res.status is GnppStatus.SOLVED, res.plan.reason
    plan = res.plan
    assert plan.level3 is not None and plan.level3.used == 1 and plan.level3.fallbacks == 0, plan.level3
    phases_in, transits, phases_out = calls[-1]
    assert len(transits) == len(plan.actions)  # one move per pick / place
    T = trajectory.T_TRAJ
    for t in transits:
        before, after = phases_in[t.phase].path, phases_out[t.phase].path
        assert len(after) == len(before) + T - 2
        np.testing.assert_allclose(after[t.row], before[t.row], atol=1e-9)  # the straight move's ends
        np.testing.assert_allclose(after[t.row + T - 1], before[t.row + 1], atol=1e-9)
        moved = np.ptp(after[t.row:t.row + T], axis=0) > 1e-9
        arm = set(FactorLib(load_robot("pr2"), _tower2()).arm_index(t.arm).tolist())
        assert set(np.flatnonzero(moved).tolist()) <= arm  # that arm alone moves; the base stays
    assert [p.path.shape for p in plan.phases] == [p.path.shape for p in phases_out]
    assert plan.validation is not None and plan.validation.ok


def test_an_optimised_move_that_collides_in_the_replay_goes_back_to_the_straight_one(monkeypatch):
    """A move driven through the table (made so on purpose) collides in the replay: that phase gets its
    straight move back and the plan passes."""

    def through_the_table(phases, transits):
        t = transits[0]
        path = phases[t.phase].path.copy()
        path[t.row + trajectory.T_TRAJ // 2, :2] = 0.0  # the base at the table's centre halfway
        out = list(phases)
        out[t.phase] = dataclasses.replace(phases[t.phase], path=path)
        return out

    res, calls = _plan(monkeypatch, through_the_table)
    assert res.status is GnppStatus.SOLVED, res.plan.reason
    assert res.plan.level3.fallbacks >= 1
    phases_in, transits, _ = calls[-1]
    t = transits[0]
    assert len(res.plan.phases[t.phase].path) == len(phases_in[t.phase].path)  # the straight move again


@pytest.fixture(scope="module")
def straight_through_a_box():
    """The PR2's right arm swinging its shoulder pan by 1 rad, a 5 cm box where the tool passes halfway."""
    model = load_robot("pr2")
    q0 = FactorLib(model, load_scene(SCENES / "tower_pr2.toml")).q_nominal
    i = model.index("r_shoulder_pan_joint")
    qa, qb = q0.copy(), q0.copy()
    qa[i] -= 0.5
    qb[i] += 0.5
    T = np.eye(4)
    T[:3, 3] = model.fk(q0, model.manipulator("right_arm").tool_frame)[:3, 3]
    return model, np.array([qa, qb]), Box("obstacle", (0.05, 0.05, 0.05), T, (1.0, 0.0, 0.0, 1.0))


def _clearance(model, path, box) -> float:
    """The least distance [m] over the path from the arm's spheres to the box, less their radii (numpy)."""
    out = np.inf
    for q in path:
        for frame, r in arm_spheres(model, "right_arm"):
            p = model.fk(q, frame)[:3, 3]
            d = float(np.linalg.norm(np.maximum(np.abs(p - box.T[:3, 3]) - np.asarray(box.size) / 2, 0.0)))
            out = min(out, d - r)
    return out


def test_a_strict_segment_detours_round_what_its_straight_move_hits(straight_through_a_box):
    """``strict`` (GNPP's straight moves): rows the warm start violates are not relaxed to it, so the path
    clears the box by the margin; the relaxed form (R-LGP's guides, known collision-free by the exact
    checker) keeps to the warm start there and reports nothing better than it."""
    model, warm, box = straight_through_a_box
    line = warm[0] + np.linspace(0.0, 1.0, 21)[:, None] * (warm[1] - warm[0])
    assert _clearance(model, line, box) < 0.0  # the straight swing goes through it
    seg = level3.Segment(warm, (box,), fix_base=True, strict=True)
    res = level3.optimize_paths(model, [seg], trajectory.T_TRAJ, manipulator="right_arm")
    assert res.ok, res.reason
    assert _clearance(model, res.paths[0], box) >= level3.MARGIN - 2e-3
    assert np.array_equal(res.paths[0][:, :3], np.repeat(warm[:1, :3], len(res.paths[0]), axis=0))  # base fixed
    relaxed = level3.optimize_paths(model, [dataclasses.replace(seg, strict=False)], trajectory.T_TRAJ,
                                    manipulator="right_arm")
    assert not relaxed.ok and relaxed.relaxed > 0
