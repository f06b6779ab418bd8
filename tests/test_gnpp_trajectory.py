"""GNPP's trajectory stage (``planning.gnpp.trajectory``): each arm's moves between its keyframes as 20
optimised waypoints, through the path NLP of R-LGP's level 3 in its ``strict`` form."""

from __future__ import annotations

import dataclasses
import itertools
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
    assert len([t for t in transits if not t.home]) == len(plan.actions)  # one move per pick / place
    # and each idle arm's move home: after every action whose arm the next action's arm is not
    arms = [a.split()[1] for a in plan.actions]
    homes = [t for t in transits if t.home]
    assert len(homes) == sum(a != b for a, b in itertools.pairwise(arms)) >= 1
    assert all(t.arm != plan.phases[t.phase].arm for t in homes)
    T = trajectory.T_TRAJ
    for t in transits:
        before, after = phases_in[t.phase].path, phases_out[t.phase].path
        earlier = sum(u.phase == t.phase and u.row < t.row for u in transits)  # optimised moves before it
        assert len(after) == len(before) + sum(u.phase == t.phase for u in transits) * (T - 2)
        r = t.row + earlier * (T - 2)  # where the move starts in the optimised phase
        np.testing.assert_allclose(after[r], before[t.row], atol=1e-9)  # the straight move's ends
        np.testing.assert_allclose(after[r + T - 1], before[t.row + 1], atol=1e-9)
        moved = np.ptp(after[r:r + T], axis=0) > 1e-9
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
    checker) keeps to the warm start there: a straight one is then its own optimum, returned as it is."""
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
    assert relaxed.ok and relaxed.relaxed > 0 and relaxed.iterations == 0  # settled, no NLP solved
    assert relaxed.acc_costs[0] == relaxed.warm_acc_costs[0] and _clearance(model, relaxed.paths[0], box) < 0.0


# Two idle arms' moves home (tower_pr2 seeds 4 and 1, gnpp_trn) that the replay rejected when straight:
# (arm, its joints LIFT above its last keyframe, what it holds (object, T_tool_obj), the resting objects'
# poses [x, y, z, yaw]). Seed 4: the right hand, up from stacking b5, swept its fingertips through b5;
# seed 1: the left hand, up from picking b4, swept b4 through b6.
HOME_MOVES = {
    "fingers_through_the_block_just_stacked": (
        "right_arm", [-0.1421, -0.3758, -1.9525, -0.5507, -0.5244, -1.0304, -0.7392], None,
        {"b1": [0.0187, 0.0707, 0.748, 0.8203], "b2": [0.025, 0.0751, 0.801, -0.8049],
         "b3": [0.03, 0.076, 0.854, 0.7679], "b4": [0.0284, 0.0732, 0.907, -0.7181],
         "b5": [0.0276, 0.0681, 0.96, 0.992]}),
    "held_block_through_a_resting_one": (
        "left_arm", [0.411, -0.1164, 2.1427, -0.557, 1.1244, -0.6462, -0.1579],
        ("b4", [[0.0, 0.67656, -0.73639, 0.0], [1.0, 0.0, 0.0, 0.00404], [0.0, -0.73639, -0.67656, 0.0],
                [0.0, 0.0, 0.0, 1.0]]),
        {"b1": [0.0163, 0.0709, 0.748, -0.8386], "b3": [0.3762, -0.1554, 0.745, 0.0496],
         "b5": [0.2932, 0.1437, 0.745, -0.1574], "b6": [-0.1837, -0.002, 0.745, -0.0969]}),
}


@pytest.mark.parametrize("case", sorted(HOME_MOVES))
def test_an_idle_arms_move_home_that_sweeps_through_a_block_is_optimised_clear_of_it(case):
    """The state a replay rejected: the straight move home collides (checked, so the case still is one);
    the trajectory stage's move home (``Transit.home``) replays collision-free, the same ends."""
    from rlgp_exec.planning.gnpp.motion import Transit
    from rlgp_exec.planning.validate import Phase, validate_plan
    from rlgp_exec.scene.types import StartState

    arm, q_up, held, resting = HOME_MOVES[case]
    base = load_scene(SCENES / "tower_pr2.toml")
    kept = {*resting, *([held[0]] if held else [])}
    objects = tuple(dataclasses.replace(o, pose=tuple(resting.get(o.name, o.pose))) for o in base.objects
                    if o.name in kept)
    goal = tuple(lit for lit in base.goal.literals if set(lit.args) <= {*kept, "goal_region"})
    scene = dataclasses.replace(base, objects=objects, goal=dataclasses.replace(base.goal, literals=goal))
    lib = FactorLib(load_robot("pr2"), scene)
    grip = None if held is None else (held[0], np.array(held[1]))
    replay = scene if held is None else dataclasses.replace(
        scene, start=StartState(held=held[0], arm=arm, tool_obj=tuple(np.ravel(held[1]))))
    straight = Phase(np.array([lib.full_q({arm: np.array(q_up)}), lib.full_q({})]), grip and grip[0], arm=arm)
    before = validate_plan(replay, [straight])
    assert not before.collision_free, "the straight move home no longer collides: not the failing state"
    poses = {o: np.array(w) for o, w in resting.items()}
    traj = trajectory.Trajectories(lib)
    out, originals = traj.optimise([straight], [Transit(0, 0, arm, grip, poses, home=True)])
    assert set(originals) == {0} and traj.stats.solved == 1
    path = out[0].path
    assert len(path) == trajectory.T_TRAJ
    np.testing.assert_allclose(path[[0, -1]], straight.path, atol=1e-9)
    after = validate_plan(replay, out)
    assert after.collision_free, after.collisions


def test_a_strict_straight_move_clear_of_every_box_is_its_own_optimum(straight_through_a_box):
    """A straight move (zero acceleration: the objective's least) that clears every row at every checkpoint
    is left out of the NLP and kept as it is; in one call with a move that needs a detour, only that one
    is optimised."""
    model, warm, box = straight_through_a_box
    aside = dataclasses.replace(box, T=box.T @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, -0.3], [0, 0, 0, 1.0]]))
    T = trajectory.T_TRAJ
    clear = level3.Segment(warm, (aside,), fix_base=True, strict=True)
    res = level3.optimize_paths(model, [clear], T, manipulator="right_arm")
    assert res.ok and res.iterations == 0 and res.n_var == 0, res
    line = warm[0] + np.linspace(0.0, 1.0, T)[:, None] * (warm[1] - warm[0])
    np.testing.assert_allclose(res.paths[0], line, atol=1e-9)
    assert _clearance(model, res.paths[0], aside) >= level3.MARGIN
    through = level3.Segment(warm, (box,), fix_base=True, strict=True)
    both = level3.optimize_paths(model, [clear, through], T, manipulator="right_arm")
    alone = level3.optimize_paths(model, [through], T, manipulator="right_arm")
    assert both.ok and both.iterations > 0 and both.n_var == alone.n_var
    np.testing.assert_allclose(both.paths[0], line, atol=1e-9)
    np.testing.assert_allclose(both.paths[1], alone.paths[0], atol=1e-6)
    assert _clearance(model, both.paths[1], box) >= level3.MARGIN - 2e-3
