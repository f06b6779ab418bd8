"""Level 3 (``planning.nlp.path``): the full-path NLP on real guided paths of pick_place_pr2."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from rlgp_exec.planning.nlp import path as level3
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.factors import RobotSymbols
from rlgp_exec.planning.nlp.keyframes import W_BASE
from rlgp_exec.reach.ik import arm_spheres
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.types import Literal

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"


def _plan_block_a(level3):
    """Plan pick block_a, place it on the tray (pick_place_pr2, that the whole goal) with ``level3``
    standing in for ``optimize_paths`` (same arguments). Returns (model, plan)."""
    import rlgp_exec.planning.sequence as sequence

    real = sequence.optimize_paths
    sequence.optimize_paths = lambda model, segments, T, **kw: level3(real, model, segments, T, **kw)
    scene = load_scene(SCENES / "pick_place_pr2.toml")
    scene = replace(scene, goal=replace(scene.goal, literals=(Literal("on", ("block_a", "tray")),)))
    geo = sequence.SequenceGeometry(scene)
    try:
        return geo.model, geo.plan_actions([Action("pick", "block_a"), Action("place", "block_a", "tray")])
    finally:
        sequence.optimize_paths = real
        geo.close()


@pytest.fixture(scope="module")
def planned():
    """The plan of ``_plan_block_a`` with level 3 as it is, and what level 3 was given and returned."""
    calls = []

    def spy(real, model, segments, T, **kw):
        res = real(model, segments, T, **kw)
        calls.append((segments, T, kw, res))
        return res

    model, plan = _plan_block_a(spy)
    assert len(calls) == 1, "level 3 ran once (the first, vertical-grasp attempt)"
    return model, plan, calls[-1]


def _box_distance(p: np.ndarray, box) -> float:
    """Exact distance [m] from a world point to a box (0 inside), numpy: independent of the NLP's sdf."""
    local = np.linalg.solve(box.T, np.r_[p, 1.0])[:3]
    return float(np.linalg.norm(np.maximum(np.abs(local) - np.asarray(box.size) / 2, 0.0)))


def test_level3_paths_keep_their_ends_limits_and_velocities(planned):
    model, _, (segments, T, _, res) = planned
    assert res.ok, res.reason
    lim = model.limits
    for seg, path, duration in zip(segments, res.paths, res.durations_s, strict=True):
        assert path.shape == (T, model.nq)
        assert np.abs(lim.difference(path[0], seg.warm[0])).max() < 1e-9  # the fixed ends (keyframe side)
        assert np.abs(lim.difference(path[-1], seg.warm[-1])).max() < 1e-9
        bounded = ~lim.continuous
        assert np.all(path[:, bounded] >= lim.lower[bounded] - 1e-6)
        assert np.all(path[:, bounded] <= lim.upper[bounded] + 1e-6)
        step = np.array([np.abs(lim.difference(b, a)) for a, b in itertools.pairwise(path)])
        assert np.all(step <= lim.velocity * duration / (T - 1) + 1e-6)


def test_level3_keeps_the_arm_spheres_off_the_world_boxes(planned):
    """Every arm sphere at least its radius + MARGIN from every box at every inner waypoint, unless the
    warm start itself came closer there (those rows are bounded by the warm start's value)."""
    model, _, (segments, T, _, res) = planned
    spheres = arm_spheres(model)
    checked = 0
    for seg, path in zip(segments, res.paths, strict=True):
        z = level3._unwrapped(model, np.arange(model.nq), seg.warm)
        warm, _ = level3.resample(z, model.limits.velocity, T)
        for k in range(1, T - 1):
            for frame, r in spheres:
                p_out = model.fk(path[k], frame)[:3, 3]
                p_warm = model.fk(model.limits.wrap(warm[k]), frame)[:3, 3]
                for box in seg.boxes:
                    need = min(r + level3.MARGIN, _box_distance(p_warm, box))
                    assert _box_distance(p_out, box) >= need - 2e-3, (frame, box.name, k)
                    checked += 1
    assert checked > 0


def test_level3_is_smoother_than_its_warm_start(planned):
    """The acceleration cost of the returned paths, recomputed here, is at most the resampled guide's."""
    model, _, (segments, T, _, res) = planned
    w = np.r_[np.full(3, W_BASE), np.ones(model.nq - 3)]

    def acc(z: np.ndarray) -> float:
        a = z[2:] - 2 * z[1:-1] + z[:-2]
        return float(np.sum(w * a**2))

    out = sum(acc(level3._unwrapped(model, np.arange(model.nq), p)) for p in res.paths)
    warm = 0.0
    for seg in segments:
        z = level3._unwrapped(model, np.arange(model.nq), seg.warm)
        warm += acc(level3.resample(z, model.limits.velocity, T)[0])
    assert out <= warm + 1e-9
    assert out < 0.5 * warm  # and by a real margin: the guides bend at their waypoints


def test_level3_plan_replays_collision_free(planned):
    """The plan with the level-3 paths in it passes the PyBullet replay (1 cm steps) with none of them
    put back to its guided path."""
    _, plan, _ = planned
    assert plan.success, plan.reason
    assert plan.level3 is not None and plan.level3.used == 1 and plan.level3.fallbacks == 0
    assert plan.level3.acc_cost is not None and plan.level3.acc_cost <= plan.level3.warm_acc_cost


def _blocks(model, segments, T, kw):
    """Level 3's blocks of ``segments`` (fresh: a solve adds rows to them), with idx and the weights."""
    manip = model.manipulator(None)
    idx = np.array([*model.group("base"), *model.group(manip.group)])
    w = np.r_[np.full(3, W_BASE), np.ones(len(idx) - 3)]
    self_rows = level3.self_rows_function(model, kw["self_spheres"], kw["body"])
    z = ca.SX.sym("z", len(idx))
    rs = RobotSymbols(model, segments[0].warm[0], manip.name, z, frames=self_rows.frames)
    rows = (self_rows.rows(rs), self_rows.lower)
    return [level3._block(model, rs, rows, idx, seg, T, kw["hand"]) for seg in segments], idx, w


def test_level3_objective_is_the_acceleration_cost_at_any_point(planned):
    """The NLP's objective (a quadratic form built once) equals the acceleration cost of the paths its
    variables stand for (numpy, ``_acc_cost``), at random points around the warm start."""
    model, _, (segments, T, kw, _) = planned
    blocks, idx, w = _blocks(model, segments, T, kw)
    solver = level3._nlp(model, blocks, idx, w, T, 10)[0]
    x0 = np.concatenate([b.Zw[1:-1].reshape(-1) for b in blocks])
    rng = np.random.default_rng(0)
    for scale in (0.0, 0.1, 1.0):
        xv = x0 + scale * rng.normal(size=x0.size)
        want, at = 0.0, 0
        for b in blocks:
            inner = xv[at:at + (T - 2) * len(idx)].reshape(T - 2, len(idx))
            at += inner.size
            want += level3._acc_cost(np.vstack([b.Zw[0], inner, b.Zw[-1]]).T, w)
        got = float(solver.get_function("nlp_f")(xv, []))
        assert got == pytest.approx(want, rel=1e-9, abs=1e-9)


def test_level3_jacobian_grows_linearly_with_the_number_of_segments(planned):
    """The NLP of k segments (``_nlp``, assembled from their structure) has k times one segment's variables,
    rows and Jacobian non-zeros."""
    model, _, (segments, T, kw, _) = planned
    blocks, idx, w = _blocks(model, segments[:1], T, kw)
    sizes = {}
    for k in (1, 2, 4):
        _, x, g, jac, *_ = level3._nlp(model, blocks * k, idx, w, T, 1)
        sizes[k] = (x.numel(), g.numel(), jac.sparsity().nnz())
    n1 = np.array(sizes[1])
    assert n1.min() > 0
    assert np.array_equal(np.array(sizes[2]), 2 * n1)
    assert np.array_equal(np.array(sizes[4]), 4 * n1)


def test_level3_segment_by_segment_is_the_whole_path_optimum(planned):
    """The segments share no variable: solving each alone (as ``optimize_paths`` does) finds the optimum
    of the whole-path NLP over all of them."""
    model, _, (segments, T, kw, _) = planned
    assert len(segments) >= 2
    blocks, idx, w = _blocks(model, segments, T, kw)
    joint = level3._solve(model, blocks, idx, w, T, 200)
    blocks, idx, w = _blocks(model, segments, T, kw)
    alone = [level3._solve(model, [b], idx, w, T, 200) for b in blocks]
    assert joint.violation <= level3.FEAS_TOL and all(a.violation <= level3.FEAS_TOL for a in alone)
    # to IPOPT's tolerance (level3.TOL): its iterates, and where it stops, differ; the larger problem's
    # stop is the earlier one, so the segments alone may end a little lower, never higher
    assert sum(a.cost for a in alone) <= joint.cost * (1 + 1e-2)
    assert sum(a.cost for a in alone) == pytest.approx(joint.cost, rel=5e-2)
    for Z_joint, a in zip(joint.paths.values(), alone, strict=True):
        (Z_alone,) = a.paths.values()
        assert np.abs(Z_joint - Z_alone).max() < 1e-2


def _violation_everywhere(b, Z: np.ndarray) -> float:
    """The largest violation [m] of every collision row of block b at every checkpoint of its path Z (T, n),
    each kept row against its bound at that checkpoint, the rows left out against their own."""
    pts = level3._checkpoints(Z)
    vals = np.asarray(b.g_all.map(len(pts))(pts.T)).reshape(len(b.lb_all), -1)
    lb = np.repeat(b.lb_all[:, None], len(pts), axis=1)
    lb[b.keep] = b.lb
    return float(np.max(np.r_[(lb - vals).reshape(-1), 0.0]))


def test_level3_rows_left_out_where_far_hold_there_or_are_put_back(planned):
    """A large block has its rows only at the checkpoints where they are near active (``_Block.on``); the
    solution keeps every row at every checkpoint all the same. With every row left out everywhere, the
    first solve cuts through the obstacles, and the rows it violates are put back at every checkpoint."""
    model, _, (segments, T, kw, _) = planned
    blocks, idx, w = _blocks(model, segments, T, kw)
    big = max(range(len(blocks)), key=lambda i: blocks[i].on.size)
    b = blocks[big]
    assert b.on.size >= level3.PRUNE_MIN and 0 < b.on.sum() < b.on.size
    res = level3._solve(model, [b], idx, w, T, 200)
    assert res.violation <= level3.FEAS_TOL
    assert _violation_everywhere(b, res.paths[id(b)]) <= level3.FEAS_TOL
    (b,), _, _ = _blocks(model, [segments[big]], T, kw)
    b.on[:] = False
    res = level3._solve(model, [b], idx, w, T, 200)
    back = b.on.all(axis=1)
    assert back.any() and not b.on[~back].any(), "a violated row is put back at every checkpoint, none elsewhere"
    assert res.violation <= level3.FEAS_TOL
    assert _violation_everywhere(b, res.paths[id(b)]) <= level3.FEAS_TOL


def test_level3_in_two_processes_is_level3_in_one(planned):
    """The segments solved half in a forked child (``planning.forked``) give the same result, bit for bit."""
    model, _, (segments, T, kw, _) = planned
    one = level3.optimize_paths(model, segments, T, workers=1, **kw)
    two = level3.optimize_paths(model, segments, T, workers=2, **kw)
    assert one.statuses == two.statuses and one.iterations == two.iterations and one.reason == two.reason
    assert one.acc_costs == two.acc_costs and one.durations_s == two.durations_s
    for a, b in zip(one.paths, two.paths, strict=True):
        assert np.array_equal(a, b)


def test_a_segment_level3_fails_on_keeps_its_warm_start_and_the_others_their_optimum(planned, monkeypatch):
    """Segment by segment: when one segment's NLP ends infeasible, that segment gets its (resampled) warm
    start back and the reason names it; the others are optimised as they would be alone."""
    model, _, (segments, T, kw, _) = planned
    want = level3.optimize_paths(model, segments, T, **kw)
    assert want.ok and len(segments) >= 2
    real, calls = level3._solve, []

    def first_fails(model, blocks, *a):
        r = real(model, blocks, *a)
        calls.append(r)
        return replace(r, violation=1.0, status="Maximum_Iterations_Exceeded") if len(calls) == 1 else r

    monkeypatch.setattr(level3, "_solve", first_fails)
    res = level3.optimize_paths(model, segments, T, workers=1, **kw)  # one process: one list of calls
    assert res.optimised == (False, *[True] * (len(segments) - 1)) and not res.ok
    assert res.statuses[0] is level3.PathStatus.INFEASIBLE and "segment 0" in res.reason
    core = [*model.group("base"), *model.group(model.manipulator(None).group)]
    moving = {int(j) for seg in segments for j in np.flatnonzero(np.ptp(seg.warm, axis=0) > 1e-9)}
    idx = np.array([*core, *sorted(moving - set(core))])  # and the torso, when a segment raises it
    Zw, _ = level3.resample(level3._unwrapped(model, idx, segments[0].warm), model.limits.velocity[idx], T)
    for q, z in zip(res.paths[0], Zw, strict=True):
        warm = q.copy()
        warm[idx] = z
        assert np.abs(model.limits.difference(q, warm)).max() < 1e-9
    assert res.acc_costs[0] == pytest.approx(res.warm_acc_costs[0])
    for got, ref in zip(res.paths[1:], want.paths[1:], strict=True):
        np.testing.assert_allclose(got, ref, atol=1e-9)


def test_a_level3_path_that_collides_in_the_replay_falls_back_to_the_guided_path():
    """Algorithm 1's replanning when level 3 fails: a level-3 path driven through the table (here made
    so on purpose) collides in the replay; that phase gets its guided path back and the plan passes."""
    from dataclasses import replace as dc_replace

    def through_the_table(real, model, segments, T, **kw):
        res = real(model, segments, T, **kw)
        bad = res.paths[0].copy()
        bad[T // 2, :2] = 0.0  # the base at the table's centre
        return dc_replace(res, paths=(bad, *res.paths[1:]))

    _, plan = _plan_block_a(through_the_table)
    assert plan.success, plan.reason
    assert plan.level3.fallbacks == 1 and plan.level3.acc_cost is None
    assert np.linalg.norm(plan.phases[0].path[:, :2], axis=1).min() > 0.3  # not through the table any more


def test_level3_processes_come_from_the_environment(monkeypatch):
    from rlgp_exec.errors import RlgpError

    monkeypatch.delenv(level3.PROCESSES_ENV, raising=False)
    assert level3.default_workers() == 1  # the other core is the HAL's and perception's
    monkeypatch.setenv(level3.PROCESSES_ENV, "2")
    assert level3.default_workers() == 2
    monkeypatch.setenv(level3.PROCESSES_ENV, "two")
    with pytest.raises(RlgpError, match="RLGP_EXEC_L3_PROCESSES='two'"):
        level3.default_workers()


@pytest.mark.parametrize(("n", "m", "blocks"), [(11, 10, 1), (10, 1, 2), (4, 3, 3)])
def test_the_objective_assembled_from_its_operators_is_the_acceleration_cost(n, m, blocks):
    """``_acc_quadratic`` (0.5 x' H x + b' x + c, from the second differences): ``_acc_cost`` of every
    block's path, the fixed ends included, at random waypoints; H is its Hessian, constant."""
    rng = np.random.default_rng(n + m + blocks)
    w = np.r_[np.full(3, W_BASE), np.ones(n - 3)]
    ends = [(rng.normal(size=n), rng.normal(size=n)) for _ in range(blocks)]
    H, b, c = level3._acc_quadratic(w, m, ends)
    H = np.asarray(ca.densify(H))
    for _ in range(3):
        x = rng.normal(size=n * m * blocks)
        paths = [np.c_[z0, x[k * n * m:(k + 1) * n * m].reshape(m, n).T, zT] for k, (z0, zT) in enumerate(ends)]
        want = sum(level3._acc_cost(Z, w) for Z in paths)
        assert 0.5 * x @ H @ x + b @ x + c == pytest.approx(want, rel=1e-12)
    assert np.allclose(H, H.T) and np.all(np.linalg.eigvalsh(H) > 0.0)  # convex: a straight path is its least


def test_waypoint_bounds_keep_the_wrist_within_its_keyframe_limits_but_where_the_warm_start_is_not():
    """``_waypoint_bounds``: the PR2's wrist flex stays above its keyframe limit (fingers clear of the
    forearm) at every inner waypoint, but no higher than the warm start where that starts below it (the
    tucked start); joints without such limits keep their bounds at every waypoint."""
    from rlgp_exec.robot import load_robot

    model = load_robot("pr2")
    idx = np.array([*model.group("base"), *model.group("right_arm")])
    lo, hi = np.full(idx.size, -5.0), np.full(idx.size, 5.0)
    wrist = list(idx).index(model.index("r_wrist_flex_joint"))
    inner = np.zeros((6, idx.size))
    inner[:, wrist] = [-1.85, -1.80, -1.70, -1.60, -1.76, -1.0]
    lo_w, hi_w = level3._waypoint_bounds(model, idx, lo, hi, inner)
    limit = model.config.keyframe_limits["r_wrist_flex_joint"][0]
    assert np.allclose(lo_w[:, wrist], [-1.85, -1.80, limit, limit, -1.76, limit])
    assert np.allclose(hi_w[:, wrist], 0.0)  # the limit's upper end
    others = np.arange(idx.size) != wrist
    assert np.all(lo_w[:, others] == -5.0) and np.all(hi_w[:, others] == 5.0)
