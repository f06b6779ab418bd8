"""``rlgp-exec bench reachability SCENE``: build time, graph size, query times, replayed path validity.

Queries join random pairs of the graph's nodes' task-space points (reachable by construction), each
asked once uncached and once reversed (answered by the solution library). Every returned path is
replayed in PyBullet at a quarter of the edge step, with the robot's plain collision check (no
clearance), against the fixtures: ``path_valid_rate`` is the fraction that holds.
"""

from __future__ import annotations

import os
import platform
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from rlgp_exec.reach.build import build_graph, nominal_q
from rlgp_exec.reach.checker import WorldChecker
from rlgp_exec.reach.graph import RGParams
from rlgp_exec.reach.ik import ReachIK
from rlgp_exec.reach.query import ReachabilityPlanner, interpolate
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene
from rlgp_exec.world.pybullet_world import build_world

__all__ = ["run_reachability_bench"]


def run_reachability_bench(
    scene_path: str | Path, samples: int = 200, queries: int = 100, seed: int = 0, workers: int | None = None
) -> dict:

    scene = load_scene(scene_path)
    model = load_robot(scene.robot.name)
    params = RGParams(samples=samples, seed=seed)
    graph, stats = build_graph(scene, None, params, workers)
    checker = WorldChecker(scene, model.manipulator().group)
    ik = ReachIK(model, scene, nominal_q(model, scene))
    planner = ReachabilityPlanner(graph, ik, checker, rng_seed=seed)
    replay = build_world(replace(scene, objects=()), tags=False, collision_only=True)
    rng = np.random.default_rng(seed)
    nodes0 = graph.alive
    edges0 = graph.G.number_of_edges()
    runs = []
    try:
        for k in range(queries):
            i, j = rng.choice(nodes0, 2, replace=False)
            res = planner.query(graph.X[i], graph.X[j])
            t0 = time.perf_counter()
            back = planner.query(graph.X[j], graph.X[i])
            cached_ms = (time.perf_counter() - t0) * 1e3
            valid = None
            if res.ok:
                fine = np.vstack(
                    [
                        interpolate(graph, a, b, params.edge_step / 4)
                        for a, b in zip(res.path[:-1], res.path[1:], strict=False)
                    ]
                )
                valid = not any(replay.robot.in_collision(q) for q in fine)
            runs.append(
                {
                    "query": k,
                    "status": res.status.value,
                    "query_ms": res.query_ms,
                    "cached_ms": cached_ms,
                    "cached_hit": back.cached,
                    "waypoints": int(res.path.shape[0]),
                    "cost": res.cost,
                    "valid": valid,
                }
            )
    finally:
        replay.close()
        checker.close()
    ok = [r for r in runs if r["status"] == "ok"]
    return {
        "task": f"reachability:{scene.name}",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "runs": runs,
        "summary": {
            "build_time_s": stats.build_time_s,
            "workers": workers or os.cpu_count(),
            "nodes": samples,
            "nodes_built": len(nodes0),
            "edges": int(edges0),
            "edges_after_queries": int(graph.G.number_of_edges()),
            "ik_attempts": stats.attempts,
            "rejected_ik": stats.rejected_ik,
            "rejected_collision": stats.rejected_collision,
            "queries": queries,
            "query_success_rate": len(ok) / queries,
            "query_ms_median": float(np.median([r["query_ms"] for r in runs])),
            "query_ms_p90": float(np.percentile([r["query_ms"] for r in runs], 90)),
            "query_cached_ms_median": float(np.median([r["cached_ms"] for r in ok])) if ok else None,
            "path_valid_rate": (sum(bool(r["valid"]) for r in ok) / len(ok)) if ok else None,
            "nodes_after_queries": int(graph.G.number_of_nodes()),
            "counters": planner.counters,
        },
    }
