"""``rlgp-exec bench SCENE --planners rlgp,lgp --seeds N``: planners side by side, interleaved seed by
seed (so their ratio holds on a noisy machine), each plan validated by replay.

Seed k randomises the scene's object poses within its ``random`` ranges (seed 0 is the file as
written). A run that fails is recorded with its reason. The reachability graph is built once per
scene (cached) and not counted in planning time; its build time is reported separately.
"""

from __future__ import annotations

import os
import platform
import sys
import time
from pathlib import Path

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.registry import plan, planner_names
from rlgp_exec.reach import load_or_build
from rlgp_exec.scene import load_scene, randomize

__all__ = ["run_planner_bench"]


def _median(xs: list[float]) -> float | None:
    return float(np.median(xs)) if xs else None


def run_planner_bench(scene_path: str | Path, planners: list[str], seeds: int) -> dict:
    valid = planner_names()
    bad = [p for p in planners if p not in valid]
    if bad:
        raise RlgpError(f"unknown planner(s) {bad}; valid: {valid}")
    base = load_scene(scene_path)
    _, stats = load_or_build(base)
    runs = []
    for seed in range(seeds):
        scene = base if seed == 0 else randomize(base, seed)
        for name in planners:
            t0 = time.perf_counter()
            result = plan(scene, name, seed=seed)
            wall = time.perf_counter() - t0
            runs.append({**result.summary(), "seed": seed, "wall_s": wall})
            print(
                f"  seed {seed:3d} {name:9s} {'ok  ' if result.success else 'FAIL'} {result.planning_time_s:7.2f} s "
                f"{result.reason[:100] if not result.success else ''}",
                file=sys.stderr,
            )
    summary = {}
    for name in planners:
        rs = [r for r in runs if r["planner"] == name]
        ok = [r for r in rs if r["success"]]
        times = [r["planning_time_s"] for r in ok]
        summary[name] = {
            "success_rate": len(ok) / len(rs) if rs else 0.0,
            "time_s_median": _median(times),
            "time_s_p90": float(np.percentile(times, 90)) if times else None,
            "base_path_m_median": _median([r["base_path_length_m"] for r in ok]),
            "steps_median": _median([r["n_steps"] for r in ok]),
            "n_nlp_median": _median([r["n_nlp"] for r in ok]),
        }
        counted = [r["counters"] for r in rs if r.get("counters")]
        if counted:  # planner-specific counters (GNPP: Table I's N0, N, NLPs), medians over the runs
            ok_counted = [r["counters"] for r in ok if r.get("counters")]
            summary[name].update(
                {
                    "n0_median": _median([c["n0"] for c in counted if c.get("n0") is not None]),
                    "n_median": _median([c["n"] for c in ok_counted if c.get("n") is not None]),
                    "nlp_median_all_runs": _median([c["nlp"] for c in counted if "nlp" in c]),
                    "conflicts_median": _median([c["conflicts"] for c in counted if "conflicts" in c]),
                }
            )
    return {
        "task": base.name,
        "seeds": seeds,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "graph_build_s": stats.build_time_s,
        "graph_from_cache": stats.from_cache,
        "runs": runs,
        "summary": summary,
    }
