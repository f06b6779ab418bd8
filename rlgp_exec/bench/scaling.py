"""``rlgp-exec bench scaling``: how the planners scale with the number of objects.

Each run plans one generated sorting scene (``scene.generate.sorting_scene(robot, n, seed)``: ``n``
blocks onto two trays, layout drawn with ``seed``) with one planner, in a child process of its own
(``bench.run_isolated``), under the given :class:`PlanLimits` and a wall-clock cap. Runs are interleaved
planner by planner for each (robot, n, seed), so the planners' ratio holds on a noisy machine.

Each run's record holds robot, N, seed, planner, success (validated by replay: ``Plan.success``),
``cpu_s`` and ``wall_s`` [s] of the planning process, and the reason it failed. The summary gives, per
planner and N (as a string key, over both robots) and per robot, the success rate and the median CPU
time: ``time_s_median`` over the successful runs (``None`` if none), ``time_s_median_all`` over every run
(a failed run counts with the time it spent before giving up).
"""

from __future__ import annotations

import logging
import os
import platform
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from rlgp_exec.bench.planners import run_isolated
from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.limits import DEFAULT_LIMITS, PlanLimits
from rlgp_exec.planning.registry import planner_names
from rlgp_exec.scene.generate import MAX_SORTING_OBJECTS, ROBOTS, sorting_scene

__all__ = ["ScalingJob", "parse_counts", "plot_scaling", "run_scaling_bench", "scaling_jobs", "summarise"]

log = logging.getLogger(__name__)
SCALING_TIME_BUDGET_S = 60.0  # [s] CPU per run unless the limits say otherwise: a failing run costs at most this
WALL_SLACK = 3.0  # a run's wall-clock cap: this many times its CPU budget (a loaded machine), plus the set-up
WALL_SETUP_S = 60.0  # [s] loading the robot and building the reachability graph, before the budget starts

OnRun = Callable[[dict, int, int], None]


@dataclass(frozen=True)
class ScalingJob:
    """One run: ``planner`` on ``sorting_scene(robot, n, seed)``."""

    robot: str
    n: int
    seed: int
    planner: str


def parse_counts(text: str) -> tuple[int, ...]:
    """``--n``: a range ``A..B`` (both included) or a list ``A,B,C`` of object counts."""
    try:
        if ".." in text:
            lo, hi = (int(v) for v in text.split("..", 1))
            counts = tuple(range(lo, hi + 1))
        else:
            counts = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise RlgpError(f"--n {text!r}: give a range A..B or a list A,B,C of whole numbers") from None
    bad = [n for n in counts if not 1 <= n <= MAX_SORTING_OBJECTS]
    if not counts or bad:
        raise RlgpError(
            f"--n {text!r}: object counts must lie in 1..{MAX_SORTING_OBJECTS} (two trays); got {bad or 'none'}"
        )
    return counts


def scaling_jobs(
    robots: Sequence[str], counts: Sequence[int], seeds: int, planners: Sequence[str]
) -> list[ScalingJob]:
    """Every run of the sweep, the planners interleaved for each (robot, n, seed); arguments checked."""
    bad_robots = [r for r in robots if r not in ROBOTS]
    if not robots or bad_robots:
        raise RlgpError(f"--robots {','.join(robots)!r}: unknown {bad_robots}; valid: {list(ROBOTS)}")
    valid = planner_names()
    bad = [p for p in planners if p not in valid]
    if not planners or bad:
        raise RlgpError(f"--planners: unknown planner(s) {bad}; valid: {valid}")
    if seeds < 1:
        raise RlgpError(f"--seeds {seeds}: must be at least 1")
    return [ScalingJob(r, n, s, p) for n in counts for r in robots for s in range(seeds) for p in planners]


def _record(job: ScalingJob, rec: dict) -> dict:
    return {
        "robot": job.robot, "N": job.n, "seed": job.seed, "planner": job.planner, "success": bool(rec["success"]),
        "cpu_s": rec.get("cpu_s"), "wall_s": rec["wall_s"], "planning_time_s": rec["planning_time_s"],
        "n_steps": rec["n_steps"], "n_nlp": rec["n_nlp"], "reason": rec["reason"],
    }


def _median(xs: Iterable[float | None]) -> float | None:
    vals = [float(x) for x in xs if x is not None]
    return float(np.median(vals)) if vals else None


def _cell(runs: list[dict]) -> dict[str, Any]:
    ok = [r for r in runs if r["success"]]
    # a run killed by the wall-clock cap has no CPU figure of its own: its wall time stands in
    spent = [r["cpu_s"] if r["cpu_s"] is not None else r["wall_s"] for r in runs]
    return {
        "runs": len(runs),
        "successes": len(ok),
        "success_rate": len(ok) / len(runs) if runs else 0.0,
        "time_s_median": _median(r["cpu_s"] for r in ok),
        "time_s_median_all": _median(spent),
    }


def summarise(runs: list[dict], planners: Sequence[str], robots: Sequence[str], counts: Sequence[int]) -> dict:
    """``{planner: {"N": {success_rate, time_s_median, ..., "by_robot": {robot: {...}}}}}``."""
    out: dict[str, dict[str, Any]] = {}
    for p in planners:
        out[p] = {}
        for n in counts:
            cell = [r for r in runs if r["planner"] == p and r["N"] == n]
            out[p][str(n)] = {
                **_cell(cell),
                "by_robot": {rb: _cell([r for r in cell if r["robot"] == rb]) for rb in robots},
            }
    return out


def run_scaling_bench(
    robots: Sequence[str] = ROBOTS,
    counts: Sequence[int] = tuple(range(2, 11)),
    seeds: int = 10,
    planners: Sequence[str] = ("rlgp", "gnpp"),
    limits: PlanLimits = DEFAULT_LIMITS,
    plot: str | Path | None = None,
    on_run: OnRun | None = None,
) -> dict:
    """The sweep; ``on_run(record, done, total)`` after every run (the CLI's progress lines)."""
    if limits.time_budget_s is None:
        limits = PlanLimits(SCALING_TIME_BUDGET_S, limits.max_expansions)
    assert limits.time_budget_s is not None
    jobs = scaling_jobs(robots, counts, seeds, planners)
    wall_cap = WALL_SLACK * limits.time_budget_s + WALL_SETUP_S
    runs: list[dict] = []
    t0 = time.perf_counter()
    for k, job in enumerate(jobs, 1):
        scene = sorting_scene(job.robot, job.n, job.seed)
        rec, _ = run_isolated(scene, job.planner, job.seed, limits, wall_timeout_s=wall_cap)
        runs.append(_record(job, rec))
        log.info("scaling %s N=%d seed %d %s: %s", job.robot, job.n, job.seed, job.planner,
                 "ok" if rec["success"] else rec["reason"])
        if on_run is not None:
            on_run(runs[-1], k, len(jobs))
    out: dict[str, Any] = {
        "task": "scaling",
        "robots": list(robots),
        "N": list(counts),
        "seeds": seeds,
        "planners": list(planners),
        "limits": limits.as_dict(),
        "wall_cap_s": wall_cap,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "sweep_wall_s": time.perf_counter() - t0,
        "runs": runs,
        "summary": summarise(runs, planners, robots, counts),
    }
    if plot:
        out["plot"] = str(plot_scaling(out, plot))
    return out


def plot_scaling(result: dict, path: str | Path) -> Path:
    """Two panels against N: median CPU time of every run (one line per planner and robot), success rate."""
    # local: matplotlib (~0.7 s) loads only when a plot is drawn
    import matplotlib

    matplotlib.use("Agg")
    # local: after matplotlib.use("Agg"), which must come first
    import matplotlib.pyplot as plt

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    counts = result["N"]
    fig, (ax_t, ax_s) = plt.subplots(1, 2, figsize=(11, 4.2))
    for p, by_n in result["summary"].items():
        for rb in result["robots"]:
            cells = [by_n[str(n)]["by_robot"][rb] for n in counts]
            t = [c["time_s_median_all"] if c["time_s_median_all"] is not None else np.nan for c in cells]
            ax_t.plot(counts, t, marker="o", label=f"{p} {rb}")
            ax_s.plot(counts, [c["success_rate"] for c in cells], marker="o", label=f"{p} {rb}")
    budget = result["limits"]["time_budget_s"]
    ax_t.axhline(budget, color="grey", ls="--", lw=0.8, label=f"budget {budget:g} s")
    ax_t.set(xlabel="objects N", ylabel="median CPU time per run [s]", title="planning time (every run)")
    ax_s.set(xlabel="objects N", ylabel="success rate", ylim=(-0.05, 1.05), title="success (validated by replay)")
    for ax in (ax_t, ax_s):
        ax.set_xticks(counts)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(f"sorting, {result['seeds']} seeds per N and robot")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
