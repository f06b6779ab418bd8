"""``rlgp-exec bench timing``: TOPPRA and Ruckig speed, and time-optimal vs constant-velocity timing."""

from __future__ import annotations

import logging
import platform
import time

import numpy as np

from rlgp_exec.robot import load_robot
from rlgp_exec.robot.limits import JointLimits
from rlgp_exec.timing.streamer import TRACKING_HEADROOM, Streamer
from rlgp_exec.timing.toppra_param import PchipPath, _solve, time_parameterize

__all__ = ["constant_velocity_duration", "run_timing_bench"]

log = logging.getLogger(__name__)


def constant_velocity_duration(path: np.ndarray, limits: JointLimits) -> float:
    """Naive retiming [s]: the same PCHIP path traversed at one constant path speed, the largest that
    keeps every joint within its velocity and acceleration limits everywhere (start and stop jumps
    ignored, which only favours the baseline)."""
    p = limits.unwrap(path)
    chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    geo = PchipPath(chord / chord[-1], p)
    ss = np.linspace(0.0, 1.0, 4001)
    d1, d2 = np.abs(geo(ss, 1)), np.abs(geo(ss, 2))
    with np.errstate(divide="ignore"):
        c = min(np.min(limits.velocity / d1), np.min(np.sqrt(limits.acceleration / d2)))
    return float(1.0 / c)


def run_timing_bench(seed: int = 0, repeats: int = 50, cycles: int = 2000) -> dict:
    """Median time of a verified TOPPRA retiming (and of one bare solve) for a 7-DoF, 10-waypoint path at
    100 gridpoints (the PR2 right arm), p99 Ruckig time per control cycle for 8 DoF (the HSR base + arm;
    Ruckig's own calculation time summed over the cycle's updates, the streamer following a path back
    and forth), and the TOPPRA / constant-velocity duration ratio."""
    rng = np.random.default_rng(seed)
    pr2 = load_robot("pr2")
    arm = pr2.limits.subset([pr2.joint_names[i] for i in pr2.group("right_arm")])
    lo = np.where(np.isfinite(arm.lower), arm.lower, -np.pi)
    hi = np.where(np.isfinite(arm.upper), arm.upper, np.pi)
    runs, toppra_ms, solve_ms, ratios = [], [], [], []
    log.info("TOPPRA: %d random 10-waypoint PR2 arm paths", repeats)
    for i in range(repeats):
        path = rng.uniform(lo + 0.1, hi - 0.1, size=(10, arm.n))
        t0 = time.perf_counter()
        res = time_parameterize(path, arm, gridpoints=100)
        ms = (time.perf_counter() - t0) * 1e3
        naive = constant_velocity_duration(path, arm)
        chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(path, axis=0), axis=1))]
        t1 = time.perf_counter()
        _solve(PchipPath(chord / chord[-1], path), arm, False, 100)  # one TOPPRA solve, unverified
        solve_ms.append((time.perf_counter() - t1) * 1e3)
        entry = {
            "run": i,
            "status": res.status.value,
            "toppra_ms": ms,
            "retries": res.retries,
            "duration_s": res.trajectory.duration if res.trajectory else None,
            "const_vel_s": naive,
        }
        runs.append(entry)
        if res.ok and res.trajectory is not None:
            toppra_ms.append(ms)
            ratios.append(res.trajectory.duration / naive)
    hsr = load_robot("hsr")
    names = [hsr.joint_names[i] for i in (*hsr.group("base"), *hsr.group("arm"))]
    lim8 = hsr.limits.subset(names)
    q0 = hsr.home()[[hsr.index(n) for n in names]]
    path = np.array([q0, q0 + np.r_[0.5, 0.3, 0.8, 0.3, -0.8, 0.5, 0.5, 0.4]])
    there, back = (time_parameterize(p, lim8.scaled(*TRACKING_HEADROOM)) for p in (path, path[::-1]))
    if there.trajectory is None or back.trajectory is None:
        raise RuntimeError(f"bench path could not be timed: {there.reason} / {back.reason}")
    ref, legs = there.trajectory, (there.trajectory, back.trajectory)
    _, q_ref, _, _ = ref.sample_rate(1000.0, wrap=False)
    log.info("Ruckig streamer: %d cycles at 100 Hz on the HSR's base and arm", cycles)
    streamer = Streamer(lim8, 0.01, q0)
    streamer.follow(ref)
    cycle_us, ruckig_us, calls, track_err, path_dev, first_pass = [], [], [], [], [], True
    for _ in range(cycles):
        sp = streamer.step()
        cycle_us.append(sp.compute_us)
        ruckig_us.append(sp.ruckig_us)
        calls.append(sp.ruckig_calls)
        if first_pass:  # how closely the jerk-limited setpoints follow the TOPPRA reference
            track_err.append(float(np.abs(sp.q - ref.sample(min(sp.t, ref.duration), wrap=False)[0]).max()))
            path_dev.append(float(np.min(np.linalg.norm(q_ref - sp.q, axis=1))))
        if sp.finished:  # keep it busy: back along the path, then there again, each leg from where it ended
            first_pass = False
            legs = legs[::-1]
            streamer.follow(legs[0])
    ok = [r for r in runs if r["status"] == "ok"]
    return {
        "task": "timing",
        "machine": {"cpus": __import__("os").cpu_count(), "python": platform.python_version()},
        "runs": runs,
        "summary": {
            "toppra_ms_median": float(np.median(toppra_ms)) if toppra_ms else None,
            "toppra_single_solve_ms_median": float(np.median(solve_ms)),
            "toppra_ms_p90": float(np.percentile(toppra_ms, 90)) if toppra_ms else None,
            "toppra_success_rate": len(ok) / len(runs),
            "toppra_retries_mean": float(np.mean([r["retries"] for r in runs])),
            "ruckig_us_median": float(np.median(ruckig_us)),
            "ruckig_us_p99": float(np.percentile(ruckig_us, 99)),
            "ruckig_cycle_wall_us_p99": float(np.percentile(cycle_us, 99)),
            "ruckig_resync_cycle_share": float(np.mean(np.asarray(calls) > 1)),
            "duration_ratio_toppra_vs_const_vel_median": float(np.median(ratios)) if ratios else None,
            "stream_tracking_err_max": max(track_err),
            "stream_path_deviation_max": max(path_dev),
            "stream_lookahead_s": streamer.lookahead,
            "dof_toppra": arm.n,
            "dof_ruckig": lim8.n,
        },
    }
