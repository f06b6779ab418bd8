"""``rlgp-exec bench SCENE --planners rlgp,lgp --seeds N``: planners side by side, interleaved seed by
seed (so their ratio holds on a noisy machine), each plan validated by replay.

Seed k randomises the scene's object poses within its ``random`` ranges (seed 0 is the file as
written). A run that fails is recorded with its reason. The reachability graph is built once per
scene (cached) and not counted in planning time; its build time is reported separately.

Every (seed, planner) job runs in a child process of its own (a native crash is a failed run, not the
end of the sweep); ``workers`` > 1 keeps that many running at once (``concurrent.futures``), each job
loading the scene file itself; ``cluster`` (a Dask scheduler address, e.g. ``tcp://host:8786``)
submits the same jobs to an existing Dask cluster instead (the workers must have this project
installed and the scene file at the same path; Dask ships jobs and results with its own serialisation,
pickle included: a cluster is a trusted, private network). ``plot`` writes the successful runs' base paths
(``planning.plot``).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import platform
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor, as_completed
from pathlib import Path
from queue import Empty
from typing import Any

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.limits import DEFAULT_LIMITS, PlanLimits
from rlgp_exec.planning.plot import plot_base_paths
from rlgp_exec.planning.registry import plan, planner_names
from rlgp_exec.reach import load_or_build
from rlgp_exec.scene import Scene, load_scene, randomize

__all__ = ["run_isolated", "run_job", "run_planner_bench"]

log = logging.getLogger(__name__)
CONNECT_TIMEOUT_S = 10.0  # [s] how long bench --cluster waits for the Dask scheduler


def _median(xs: list[float]) -> float | None:
    return float(np.median(xs)) if xs else None


def run_job(
    scene_source: str | Scene, planner: str, seed: int, limits: PlanLimits = DEFAULT_LIMITS
) -> tuple[dict, list[list[float]]]:
    """One bench run (in any process): its record, and the base path [[x, y], ...] [m] if it succeeded.
    ``scene_source``: a scene file (randomised with ``seed``, 0: as written) or a scene planned as given.
    The record's ``wall_s`` and ``cpu_s`` [s] are this process's, the whole planning call."""
    if isinstance(scene_source, Scene):
        scene = scene_source
    else:
        base = load_scene(scene_source)
        scene = base if seed == 0 else randomize(base, seed)
    t0, c0 = time.perf_counter(), time.process_time()
    result = plan(scene, planner, seed=seed, limits=limits)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    xy: list[list[float]] = []
    if result.success:
        xy = np.vstack([ph.path[:, :2] for ph in result.phases]).tolist() if result.phases else []
    return {**result.summary(), "seed": seed, "wall_s": wall, "cpu_s": cpu}, xy


def _child(queue, scene_source: str | Scene, planner: str, seed: int, limits: PlanLimits) -> None:
    queue.put(run_job(scene_source, planner, seed, limits))


def run_isolated(
    scene_source: str | Scene, planner: str, seed: int, limits: PlanLimits = DEFAULT_LIMITS,
    wall_timeout_s: float | None = None,
) -> tuple[dict, list[list[float]]]:
    """``run_job`` in a child process of its own: a native crash (PyBullet, OMPL, IPOPT) becomes a
    failed run with its exit code instead of the end of the sweep. ``wall_timeout_s`` [s]: a child still
    planning after this long is killed and its run recorded as failed (the planners' own budget is CPU
    time, which a stuck native call or a starved machine does not spend)."""
    ctx = mp.get_context("fork")  # fork: the scene and limits reach the child without serialising them
    queue = ctx.Queue()
    proc = ctx.Process(target=_child, args=(queue, scene_source, planner, seed, limits), daemon=True)
    t0 = time.perf_counter()
    proc.start()
    try:
        while True:
            try:
                return queue.get(timeout=1.0)
            except Empty:
                if not proc.is_alive():
                    break
                if wall_timeout_s is not None and time.perf_counter() - t0 > wall_timeout_s:
                    proc.kill()
                    proc.join()
                    return _failed(planner, seed, f"timeout: still planning after {wall_timeout_s:.0f} s wall", t0)
        proc.join()
        return _failed(planner, seed, f"crashed: the planning process ended with exit code {proc.exitcode}", t0)
    finally:
        proc.join(timeout=5.0)


def _failed(planner: str, seed: int, reason: str, t0: float) -> tuple[dict, list[list[float]]]:
    """The record of a run that ended without a plan of its own (a crash, a lost cluster worker)."""
    log.warning("seed %d %s: %s", seed, planner, reason)
    wall = time.perf_counter() - t0
    rec = {"success": False, "planner": planner, "planning_time_s": wall, "actions": [], "n_steps": 0,
           "base_path_length_m": 0.0, "collision_free": None, "goal_met": None, "n_nlp": 0,
           "nodes_expanded": 0, "reason": reason, "seed": seed, "wall_s": wall, "cpu_s": None}
    return rec, []


def _report(record: dict, done: int, total: int) -> None:
    ok = record["success"]
    cpu = record.get("cpu_s")
    spent = f"{cpu:7.2f} s CPU " if cpu is not None else ""
    log.info("[%3d/%d] seed %3d %-5s %s %s%7.2f s wall %s", done, total, record["seed"], record["planner"],
             "ok  " if ok else "FAIL", spent, record.get("wall_s", record["planning_time_s"]),
             "" if ok else record["reason"][:100])


def _submit_all(
    jobs, submit: Callable[..., Any], scene_path: str, job=run_isolated, completed=as_completed,
    limits: PlanLimits = DEFAULT_LIMITS,
) -> list[tuple[dict, list]]:
    """Every job submitted at once; ``completed``: the ``as_completed`` of the futures' kind."""
    t0 = time.perf_counter()
    futures = {submit(job, scene_path, name, seed, limits): k for k, (seed, name) in enumerate(jobs)}
    out: list[tuple[dict, list] | None] = [None] * len(jobs)
    for done, fut in enumerate(completed(futures), 1):
        k = futures[fut]
        try:
            out[k] = fut.result()
        except Exception as e:  # e.g. Dask's KilledWorker: a worker died natively on this job, thrice
            seed, name = jobs[k]
            out[k] = _failed(name, seed, f"lost: {type(e).__name__}: {e}", t0)
        _report(out[k][0], done, len(jobs))  # type: ignore[index]
    return out  # type: ignore[return-value]


def _on_cluster(jobs, address: str, scene_path: str, limits: PlanLimits) -> list[tuple[dict, list]]:
    try:
        # local: optional (the `cluster` extra), needed only for --cluster
        from dask.distributed import Client
        from dask.distributed import as_completed as dask_completed
    except ModuleNotFoundError:
        raise RlgpError(
            f"bench --cluster {address}: needs Dask's distributed scheduler in this environment "
            "(pip install 'dask[distributed]'); valid without it: --workers K"
        ) from None
    try:
        client = Client(address, timeout=CONNECT_TIMEOUT_S)
    except (OSError, TimeoutError) as e:
        raise RlgpError(
            f"bench --cluster {address}: no Dask scheduler answered within {CONNECT_TIMEOUT_S} s ({e}); "
            "start one (`dask scheduler`, then `dask worker ADDRESS` per machine) or use --workers K"
        ) from None
    with client:
        # run_job in the worker itself: Dask's workers are daemon processes, which may not start the
        # child process run_isolated would; a worker that dies on a job is replaced by its nanny
        return _submit_all(jobs, client.submit, scene_path, run_job, dask_completed, limits)


def run_planner_bench(
    scene_path: str | Path,
    planners: list[str],
    seeds: int,
    workers: int | None = None,
    cluster: str | None = None,
    plot: str | Path | None = None,
    limits: PlanLimits = DEFAULT_LIMITS,
) -> dict:
    valid = planner_names()
    bad = [p for p in planners if p not in valid]
    if bad:
        raise RlgpError(f"unknown planner(s) {bad}; valid: {valid}")
    if workers is not None and workers < 1:
        raise RlgpError(f"--workers {workers}: must be at least 1")
    scene_path = str(Path(scene_path).resolve())
    base = load_scene(scene_path)
    log.info("%s: the reachability graph (built once, cached for the runs)", base.name)
    _, stats = load_or_build(base)  # once, before any worker: they all read the cache
    jobs = [(seed, name) for seed in range(seeds) for name in planners]  # interleaved, seed by seed
    log.info("%s: %d runs (%d seeds x %s), each in a process of its own", base.name, len(jobs), seeds,
             ",".join(planners))
    t0 = time.perf_counter()
    if cluster:
        results = _on_cluster(jobs, cluster, scene_path, limits)
    elif workers and workers > 1:  # K jobs at a time, each in a process of its own (run_isolated)
        with ThreadPoolExecutor(max_workers=workers) as pool:
            results = _submit_all(jobs, pool.submit, scene_path, limits=limits)
    else:
        results = []
        for k, (seed, name) in enumerate(jobs):
            results.append(run_isolated(scene_path, name, seed, limits))
            _report(results[-1][0], k + 1, len(jobs))
    sweep_s = time.perf_counter() - t0
    runs = [r for r, _ in results]
    summary: dict[str, dict[str, Any]] = {}
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
        l3 = [(r["level3"], r["planning_time_s"]) for r in ok if r.get("level3")]
        if l3:  # R-LGP's level 3 (full-path optimisation), over the successful runs
            summary[name].update(
                {
                    "l3_time_s_median": _median([s["time_s"] for s, _ in l3]),
                    "l3_time_share_median": _median([s["time_s"] / t for s, t in l3 if t > 0]),
                    "l3_whole_plans": sum(s["acc_cost"] is not None for s, _ in l3) / len(l3),
                    "l3_fallbacks_total": sum(s["fallbacks"] for s, _ in l3),
                }
            )
        staged = [r for r in ok if r.get("stages_s")]
        if staged:  # R-LGP: where the solved runs' time went, stage by stage; "other": search, grounding, checks
            stages = {k: _median([r["stages_s"][k] for r in staged]) for k in staged[0]["stages_s"]}
            stages["other"] = _median([r["planning_time_s"] - sum(r["stages_s"].values()) for r in staged])
            summary[name]["stages_s_median"] = stages
        counted = [r["counters"] for r in rs if r.get("counters")]
        if counted:  # planner-specific counters (GNPP: Table I's N0, N, NLPs), medians over the runs
            ok_counted = [r["counters"] for r in ok if r.get("counters")]
            summary[name].update(
                {
                    "n0_median": _median([c["n0"] for c in counted if c.get("n0") is not None]),
                    "n_median": _median([c["n"] for c in ok_counted if c.get("n") is not None]),
                    "nlp_median_all_runs": _median([c["nlp"] for c in counted if "nlp" in c]),
                    "conflicts_median": _median([c["conflicts"] for c in counted if "conflicts" in c]),
                    # the planner process's CPU time of the solved runs [s]: less load-dependent than time_s
                    "cpu_s_median": _median([c["cpu_s"] for c in ok_counted if "cpu_s" in c]),
                }
            )
    out = {
        "task": base.name,
        "seeds": seeds,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "workers": 1 if cluster is None and not workers else (workers or 0),
        "cluster": cluster,
        "sweep_wall_s": sweep_s,
        "graph_build_s": stats.build_time_s,
        "graph_from_cache": stats.from_cache,
        "limits": limits.as_dict(),
        "runs": runs,
        "summary": summary,
    }
    if plot:
        paths = {name: [np.asarray(xy) for r, xy in results if r["planner"] == name and xy] for name in planners}
        title = f"{base.name}: base paths ({seeds} seeds; objects of seed 0)"
        out["plot"] = str(plot_base_paths(base, paths, plot, title))
    return out
