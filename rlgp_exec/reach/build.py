"""constructRG (Algorithm 1): sample task-space nodes, validate them by IK + collision checking, in
parallel worker processes, then connect k nearest neighbours lazily; cached per environment.

Each worker owns a PyBullet world holding the scene's fixtures only (movable objects are the
planner's business) and a :class:`ReachIK`. It draws targets uniformly in the workspace box, rejects
those inside fixtures (g_prec), warm-starts IK from its nearest node found so far (else from the base
placed so the arm's home reach lands on the target, facing it from a random side), and keeps the
configurations PyBullet finds collision-free.
"""

from __future__ import annotations

import hashlib
import logging
import math
import multiprocessing as mp
import os
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np

from rlgp_exec.planning import budget
from rlgp_exec.reach.checker import CLEARANCE, WorldChecker
from rlgp_exec.reach.graph import GraphCacheError, ReachabilityGraph, RGParams, cache_key
from rlgp_exec.reach.ik import ReachIK
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import support_surfaces
from rlgp_exec.scene.randomize import scene_hash

__all__ = ["BuildStats", "build_graph", "cache_dir", "graph_meta", "load_or_build", "nominal_q", "workspace_box"]

log = logging.getLogger(__name__)
_DEFAULT = RGParams()
BUILD_CHUNKS = 2  # seeded sampling jobs per graph, run in parallel where cores allow
WARM_RADIUS = 0.35  # [m] warm-start IK from a node this close to the target


@dataclass(frozen=True)
class BuildStats:
    build_time_s: float
    attempts: int
    rejected_precondition: int
    rejected_ik: int
    rejected_collision: int
    from_cache: bool


def cache_dir() -> Path:
    root = Path(os.environ.get("RLGP_EXEC_CACHE", Path.home() / ".cache" / "rlgp-exec"))
    return root / "reachability"


def nominal_q(model: RobotModel, scene: Scene) -> FloatArray:
    """The configuration whose non-planning joints every node keeps: the scene's start."""
    return model.home(scene.robot.base, scene.robot.joints)


def workspace_box(scene: Scene, params: RGParams) -> tuple[FloatArray, FloatArray]:
    """The sampling box [lo, hi] (3,): around the fixtures, from the lowest support surface up."""
    corners: list[FloatArray] = []
    for fx in scene.fixtures:
        hx, hy = fx.size[0] / 2, fx.size[1] / 2
        for sx in (-1, 1):
            for sy in (-1, 1):
                corners.append((fx.T @ np.array([sx * hx, sy * hy, 0.0, 1.0]))[:2])
    pts = np.array(corners)
    # fixture surfaces only: the graph (and its cache key) must not depend on where the objects are
    zs = [s.z for s in support_surfaces(replace(scene, objects=()))]
    lo = np.r_[pts.min(axis=0) - params.margin_xy, min(zs) + 0.03]
    hi = np.r_[pts.max(axis=0) + params.margin_xy, max(zs) + params.z_above]
    return lo, hi


def graph_meta(model: RobotModel, scene: Scene, manipulator: str, params: RGParams) -> dict:
    """What a saved graph must match to be reused."""
    q0 = nominal_q(model, scene)
    ik_idx = [*model.group("base"), *model.group(model.manipulator(manipulator).group)]
    fixed = {n: round(float(q0[i]), 6) for i, n in enumerate(model.joint_names) if i not in ik_idx}

    # robot.toml and the URDF PyBullet checks against (a graph built before a collision-shape change
    # keeps nodes and edges the robot no longer has, or lacks the ones it gained)
    h = hashlib.sha256((model.config.folder / "robot.toml").read_bytes())
    h.update(model.urdf.pybullet_path.read_bytes())
    robot_files = h.hexdigest()[:16]
    return {
        "robot": model.name,
        "robot_files": robot_files,
        "manipulator": manipulator,
        "scene_hash": scene_hash(scene),
        "fixed_joints": fixed,
        "params": asdict(params),
        "clearance": CLEARANCE,
    }


_FORKED: dict = {}  # the scene for forked workers (scenes hold mapping proxies, which do not pickle)


def _worker(args: tuple) -> dict:
    manipulator, params, n_target, seed, clock = args
    b = budget.active()
    if b is not None and clock is not None:  # a forked worker: the CPU time left, on its own clock
        b.forked(clock)
    scene = _FORKED["scene"]
    model = load_robot(scene.robot.name)
    checker = WorldChecker(scene, model.manipulator(manipulator).group)
    try:
        ik = ReachIK(model, scene, nominal_q(model, scene), manipulator)
        lo, hi = workspace_box(scene, params)
        rng = np.random.default_rng(seed)
        X: list[FloatArray] = []
        Q: list[FloatArray] = []
        C: list[float] = []
        stats = {"attempts": 0, "rejected_precondition": 0, "rejected_ik": 0, "rejected_collision": 0}
        max_attempts = 20 * n_target
        while len(X) < n_target and stats["attempts"] < max_attempts:
            stats["attempts"] += 1
            x0 = rng.uniform(lo, hi)
            if ik.inside_fixture(x0) is not None:
                stats["rejected_precondition"] += 1
                continue
            inits = []
            if X:
                d = np.linalg.norm(np.asarray(X) - x0, axis=1)
                j = int(np.argmin(d))
                if d[j] < WARM_RADIUS:
                    z = ik.z_of(Q[j])
                    z[:2] += x0[:2] - X[j][:2]  # carry the base along with the target
                    inits.append(z)
            inits.append(ik.guess(x0, rng.uniform(-math.pi, math.pi)))
            found = None
            for z0 in inits:
                res = ik.solve(x0, z0)
                if res.ok:
                    found = res
                    break
            if found is None:
                stats["rejected_ik"] += 1
                continue
            if checker(found.q):
                stats["rejected_collision"] += 1
                continue
            X.append(x0)
            Q.append(found.q)
            C.append(found.cost)
        return {"X": np.array(X).reshape(-1, 3), "Q": np.array(Q).reshape(-1, model.nq), "C": np.array(C), **stats}
    finally:
        checker.close()


def build_graph(
    scene: Scene, manipulator: str | None = None, params: RGParams = _DEFAULT, workers: int | None = None
) -> tuple[ReachabilityGraph, BuildStats]:
    """Sample ``params.samples`` valid nodes in BUILD_CHUNKS seeded jobs on up to ``workers`` processes and
    connect them (unchecked): the same graph whatever the core count."""
    t0 = time.perf_counter()
    model = load_robot(scene.robot.name)
    manip = model.manipulator(manipulator).name
    chunks = max(1, min(BUILD_CHUNKS, params.samples))
    shares = [params.samples // chunks + (i < params.samples % chunks) for i in range(chunks)]
    workers = max(1, min(workers or os.cpu_count() or 1, chunks))
    if workers > 1 and mp.current_process().daemon:  # a bench's planning child: it may not fork workers
        workers = 1
    clock = budget.cpu_clock() if workers > 1 else None
    jobs = [(manip, params, n, params.seed * 1000 + i, clock) for i, n in enumerate(shares)]
    _FORKED["scene"] = scene
    try:
        if workers == 1:
            results = [_worker(job) for job in jobs]
        else:  # the workers share what the budget has left (their CPU time counts once they have ended)
            with budget.shared(workers), mp.get_context("fork").Pool(workers) as pool:
                results = pool.map(_worker, jobs)
    finally:
        _FORKED.clear()
    plan_idx = np.array([*model.group("base"), *model.group(model.manipulator(manip).group)])
    g = ReachabilityGraph(model.limits, plan_idx, params, graph_meta(model, scene, manip, params))
    for r in results:
        for x, q, c in zip(r["X"], r["Q"], r["C"], strict=True):
            g.add_node(x, q, c)
    g.connect_knn()

    def total(counter: str) -> int:
        return sum(r[counter] for r in results)

    stats = BuildStats(
        time.perf_counter() - t0,
        total("attempts"),
        total("rejected_precondition"),
        total("rejected_ik"),
        total("rejected_collision"),
        False,
    )
    if g.G.number_of_nodes() < params.samples:
        log.warning(
            "reachability graph: %d of %d nodes after %d attempts",
            g.G.number_of_nodes(),
            params.samples,
            stats.attempts,
        )
    return g, stats


def load_or_build(
    scene: Scene,
    manipulator: str | None = None,
    params: RGParams = _DEFAULT,
    workers: int | None = None,
    folder: Path | None = None,
) -> tuple[ReachabilityGraph, BuildStats]:
    """ "Precompute once per environment": the cached graph when one matches, else a new one (saved)."""
    model = load_robot(scene.robot.name)
    manip = model.manipulator(manipulator).name
    meta = graph_meta(model, scene, manip, params)
    path = (folder or cache_dir()) / f"{scene.robot.name}_{cache_key(meta)}.npz"
    if path.exists():
        t0 = time.perf_counter()
        try:
            g = ReachabilityGraph.load(path, model.limits, meta)
            return g, BuildStats(time.perf_counter() - t0, 0, 0, 0, 0, True)
        except GraphCacheError as e:
            log.warning("rebuilding the reachability graph: %s", e)
    g, stats = build_graph(scene, manip, params, workers)
    g.save(path)
    return g, stats
