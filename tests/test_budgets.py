"""Budgets hold inside every stage (``planning.budget``): a plan call with CPU budget B ends within B plus a
slack, as a failed Plan whose reason names the stage, whatever the scene; held objects get a bounded sphere
cover (``nlp.hand``). Correctness, not speed: the budgets are small and the slack generous."""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from rlgp_exec.planning import budget
from rlgp_exec.planning.budget import Budget, BudgetError, cpu_clock, using
from rlgp_exec.planning.forked import fork_map
from rlgp_exec.planning.gnpp.planner import GnppStatus, plan_gnpp
from rlgp_exec.planning.nlp import path as level3
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.hand import MAX_COVER_SPHERES, _box_cover, cover_refusal
from rlgp_exec.planning.rlgp import plan_scene
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.types import Literal

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"
SLACK_S = 4.0  # [s] CPU time a plan call may run past its budget (the target: 5 s)


def _spin_until_spent(limit_s: float = 10.0) -> None:
    """Call ``budget.check()`` in a CPU-bound loop until it raises; fail after ``limit_s`` of CPU time."""
    c0 = cpu_clock()
    while cpu_clock() - c0 < limit_s:
        budget.check()
        sum(range(1000))
    pytest.fail(f"the budget did not run out within {limit_s} s of CPU time")


def test_a_spent_budget_raises_naming_the_stage_and_scope():
    b = Budget(0.2)
    with using(b), b.at("keyframes", "candidate 3"), pytest.raises(BudgetError) as err:
        _spin_until_spent()
    assert str(err.value) == "budget: 0.2 s CPU spent in keyframes of candidate 3"
    assert b.spent() < 0.2 + 0.5
    assert budget.active() is None and budget.left() == math.inf  # closed again
    budget.check()  # no budget open: nothing to check


def test_the_memory_cap_holds():
    b = Budget(60.0, memory_bytes=64 * 2**20)
    with using(b), b.at("level 3"), pytest.raises(BudgetError, match=r"^budget: memory grew by .* in level 3"):
        ballast = np.ones(32 * 2**20)  # 256 MiB, every page touched
        _spin_until_spent()
    del ballast


def test_ipopt_stops_once_the_budget_is_spent():
    x = ca.SX.sym("x", 30)
    nlp = {"x": x, "f": ca.sum1((x[1:] - x[:-1] ** 2) ** 2) + ca.sum1((1 - x) ** 2)}
    solver = ca.nlpsol("rosenbrock", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes",
                                                    **budget.ipopt_stop()})
    solver(x0=np.zeros(30))
    free = solver.stats()
    assert free["return_status"] == "Solve_Succeeded" and free["iter_count"] > 3
    b = Budget(0.01)
    with using(b):
        with pytest.raises(BudgetError):
            _spin_until_spent()
        solver(x0=np.zeros(30))
    assert solver.stats()["return_status"] == "User_Requested_Stop"
    assert solver.stats()["iter_count"] <= 1


def test_fork_map_shares_the_budget_with_its_child():
    """Each process spends at most half of what is left: the child's CPU time reaches the clock only once
    it has ended, so two processes on the whole remainder would spend it twice."""

    def spin(_k: int) -> dict:
        _spin_until_spent()
        return {}

    c0 = cpu_clock()
    b = Budget(1.0)
    with using(b), pytest.raises(BudgetError):
        fork_map(spin, [0, 1], workers=2)
    spent = cpu_clock() - c0  # the child's included: fork_map has reaped it
    assert spent < 1.0 + 0.5, spent
    assert b.deadline == pytest.approx(b.start + 1.0)  # this process's share restored


def test_a_thin_box_gets_a_capped_cover_and_a_pole_is_refused():
    fine = _box_cover(np.array([0.05, 0.05, 0.10]))
    assert len(fine) == 3  # the usual row: spacing below the cross-section's half diagonal
    size = np.array([1e-6, 1e-6, 0.1])  # ~141,000 spheres uncapped
    cover = _box_cover(size)
    assert len(cover) == MAX_COVER_SPHERES and cover_refusal(size) is None
    centres, radii = np.array([c for c, _ in cover]), np.array([r for _, r in cover])
    pts = np.random.default_rng(0).uniform(-size / 2, size / 2, (2000, 3))
    pts = np.vstack([pts, [[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)] * size / 2])
    inside = np.linalg.norm(pts[:, None] - centres[None], axis=2) <= radii[None] + 1e-12
    assert inside.any(axis=1).all()  # every point of the box in some sphere
    assert radii.max() < 0.001  # and none reaches far past it
    why = cover_refusal(np.array([0.001, 0.001, 2.0]))
    assert why is not None and f"{MAX_COVER_SPHERES} spheres" in why


def test_level3_refuses_a_held_object_it_cannot_cover_and_keeps_the_guide():
    """pick_place_pr2's block_a carried as a 2 m pole of 1 mm: its segment is not optimised (the reason
    says why), the others are."""
    import rlgp_exec.planning.sequence as sequence

    seen = []
    real = sequence.optimize_paths

    def as_pole(model, segments, T, **kw):
        poles = [replace(s, held=(np.array([0.001, 0.001, 2.0]), s.held[1])) if s.held is not None else s
                 for s in segments]
        res = real(model, poles, T, **kw)
        seen.append((poles, res))
        return res

    scene = load_scene(SCENES / "pick_place_pr2.toml")
    scene = replace(scene, goal=replace(scene.goal, literals=(Literal("on", ("block_a", "tray")),)))
    sequence.optimize_paths = as_pole
    geo = sequence.SequenceGeometry(scene)
    try:
        geo.plan_actions([Action("pick", "block_a"), Action("place", "block_a", "tray")])
    finally:
        sequence.optimize_paths = real
        geo.close()
    segments, res = seen[0]
    held = [k for k, s in enumerate(segments) if s.held is not None]
    assert held, "a segment carries the block"
    for k, status in enumerate(res.statuses):
        assert (status is level3.PathStatus.REFUSED) == (k in held)
    assert f"segment {held[0]}: held object: box" in res.reason
    for k in held:  # the guide, resampled
        assert np.allclose(res.paths[k][[0, -1]], np.asarray(segments[k].warm)[[0, -1]], atol=1e-9)


def _far(scene, km: float):
    """The scene with the robot's base ``km`` away along y (built here: a loader may refuse such files)."""
    x, y, yaw = scene.robot.base
    return replace(scene, robot=replace(scene.robot, base=(x, y + 1000.0 * km, yaw)))


@pytest.mark.parametrize(("name", "budget_s"), [("table_clearing_hsr", 0.5), ("pick_place_pr2", 0.3)])
def test_rlgp_ends_within_a_small_budget(name, budget_s):
    c0 = cpu_clock()
    plan = plan_scene(load_scene(SCENES / f"{name}.toml"), time_budget_s=budget_s)
    spent = cpu_clock() - c0
    assert not plan.success and plan.reason.startswith(f"budget: {budget_s:g} s CPU spent in "), plan.reason
    assert spent < budget_s + SLACK_S


def test_rlgp_ends_within_its_budget_with_the_base_1000_km_away():
    c0 = cpu_clock()
    plan = plan_scene(_far(load_scene(SCENES / "table_clearing_hsr.toml"), 1000.0), time_budget_s=2.0)
    spent = cpu_clock() - c0
    assert not plan.success and plan.reason.startswith("budget: 2 s CPU spent in "), plan.reason
    assert "of candidate" in plan.reason
    assert spent < 2.0 + SLACK_S


@pytest.mark.parametrize(("name", "far_km"), [("hanoi_pr2", 0.0), ("sorting_hsr", 1000.0)])
def test_gnpp_ends_within_a_small_budget(name, far_km):
    c0 = cpu_clock()
    res = plan_gnpp(_far(load_scene(SCENES / f"{name}.toml"), far_km), "gnpp_trn", timeout_s=2.0)
    spent = cpu_clock() - c0
    assert res.status is GnppStatus.TIMEOUT, res.plan.reason
    assert res.plan.reason.startswith("budget: 2 s CPU spent in ") and "of iteration" in res.plan.reason
    assert spent < 2.0 + SLACK_S


def test_a_callers_budget_bounds_the_planners_own():
    """A budget open round a planner call (a CLI's or an executive's) holds: the planner's own 90 s
    default is cut to what the caller's has left."""
    c0 = cpu_clock()
    with using(Budget(0.5)):
        plan = plan_scene(load_scene(SCENES / "table_clearing_hsr.toml"))
    assert not plan.success and plan.reason.startswith("budget: 0.5"), plan.reason
    assert cpu_clock() - c0 < 0.5 + SLACK_S


def test_rlgp_refuses_a_one_micron_block_before_any_search():
    """pick_place_pr2 with block_c 1 um thick (built here, past the loader's SIZE_MIN): refused at the
    planner's entry by the same rule, naming the block, before any graph or NLP is built."""
    from rlgp_exec.planning.capabilities import TaskRefusedError

    scene = load_scene(SCENES / "pick_place_pr2.toml")
    tiny = tuple(replace(o, size=(1e-6, 1e-6, o.size[2])) if o.name == "block_c" else o for o in scene.objects)
    with pytest.raises(TaskRefusedError, match=r"block_c \[1e-06, 1e-06, .*below SIZE_MIN"):
        plan_scene(replace(scene, objects=tiny), time_budget_s=3.0)


def test_ompl_gets_what_the_budget_has_left():
    """A base drive OMPL cannot solve (pick_place_pr2's table between the ends, the base's box no wider than
    theirs) takes its whole time limit, 30 s here; under a 0.5 s budget it ends within the budget, before
    one of its three attempts' share (10 s of OMPL's wall clock) is up."""
    import time

    from rlgp_exec.reach import WorldChecker, nominal_q
    from rlgp_exec.reach.ompl_plan import plan_ompl
    from rlgp_exec.robot import load_robot

    scene = load_scene(SCENES / "pick_place_pr2.toml")
    model = load_robot(scene.robot.name)
    checker = WorldChecker(scene, model.manipulator().group)
    try:
        q1 = nominal_q(model, scene)
        q2 = q1.copy()
        q2[1], q2[2] = -q1[1], q1[2] + math.pi  # behind the table, facing it
        assert not checker(q1) and not checker(q2)
        box = np.minimum(q1[:2], q2[:2]), np.maximum(q1[:2], q2[:2])
        c0, t0 = cpu_clock(), time.perf_counter()
        with using(Budget(0.5)):
            try:
                path = plan_ompl(checker, np.array([0, 1, 2]), q1, q2, *box, timeout=30.0)
            except BudgetError:
                path = None
        assert path is None
        assert cpu_clock() - c0 < 0.5 + SLACK_S
        assert time.perf_counter() - t0 < 10.0
    finally:
        checker.close()
