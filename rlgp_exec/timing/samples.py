"""A plan's timed trajectory as data: every phase time-parameterised as the executive times it
(:func:`~rlgp_exec.timing.plan_timing.to_trajectory`), sampled at a fixed rate, with where each action and gripper
event happens. ``plan --json`` / ``--trajectory`` write :func:`trajectory_dict`; its fields are documented
by ``docs/trajectory.schema.json``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.plan import Plan
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.timing.plan_timing import to_trajectory
from rlgp_exec.timing.trajectory import TimingError

__all__ = ["FORMAT", "VERSION", "PlanSamples", "TimedPhase", "time_plan", "trajectory_dict"]

FORMAT = "rlgp-exec/trajectory"
VERSION = 1


@dataclass(frozen=True)
class TimedPhase:
    """Phase ``index`` of the plan over [t_start, t_end] [s]; the action it completes (None: between actions)."""

    index: int
    t_start: float
    t_end: float
    action_index: int | None
    action: str | None
    arm: str | None
    held: str | None
    grasp: str | None
    release: str | None
    drives_drawer: bool


@dataclass(frozen=True)
class PlanSamples:
    """Samples of the whole plan: ``t`` (T,) [s], ``q`` (T, nq) and ``dq`` (T, nq) in ``joint_names`` order
    (base x [m], y [m], yaw [rad] first; revolute joints [rad], prismatic [m]); ``phase`` (T,) the index of
    the phase each sample belongs to."""

    joint_names: tuple[str, ...]
    rate_hz: float
    t: FloatArray
    q: FloatArray
    dq: FloatArray
    phase: np.ndarray
    phases: tuple[TimedPhase, ...]

    @property
    def duration_s(self) -> float:
        return float(self.t[-1]) if len(self.t) else 0.0


def time_plan(plan: Plan, model: RobotModel, rate_hz: float = 20.0) -> PlanSamples:
    """Time every phase of a successful ``plan`` for ``model`` and sample it at ``rate_hz``; a phase the timing
    layer refuses raises RlgpError naming it."""
    if not plan.success:
        raise RlgpError(f"no trajectory: the plan failed ({plan.reason})")
    if not (rate_hz > 0 and np.isfinite(rate_hz)):
        raise RlgpError(f"trajectory rate {rate_hz!r} Hz: must be a positive number")
    try:
        timed = to_trajectory(plan, model)
    except TimingError as e:
        raise RlgpError(str(e)) from e
    ts: list[FloatArray] = []
    qs: list[FloatArray] = []
    dqs: list[FloatArray] = []
    idx: list[np.ndarray] = []
    phases: list[TimedPhase] = []
    t = 0.0
    for k, (ph, traj) in enumerate(zip(plan.phases, timed.trajectories, strict=True)):
        t0 = t
        if traj is not None:
            tt, q, dq, _ = traj.sample_rate(rate_hz)
            if ts:  # the phase starts where the last ended (rest to rest): one sample at the joint
                tt, q, dq = tt[1:], q[1:], dq[1:]
            ts.append(tt + t0)
            qs.append(q)
            dqs.append(dq)
            idx.append(np.full(len(tt), k))
            t = t0 + traj.duration
        elif len(ph.path) == 1 and not ts:
            ts.append(np.zeros(1))
            qs.append(model.limits.wrap(ph.path[:1]))
            dqs.append(np.zeros((1, model.nq)))
            idx.append(np.full(1, k))
        a = ph.action
        phases.append(TimedPhase(
            k, t0, t, a, plan.actions[a] if a is not None and 0 <= a < len(plan.actions) else None,
            ph.arm, ph.held, ph.grasp, ph.release, ph.drives_drawer,
        ))
    if not ts:
        raise RlgpError("no trajectory: the plan has no joint path")
    return PlanSamples(
        model.joint_names, float(rate_hz), np.concatenate(ts), np.concatenate(qs), np.concatenate(dqs),
        np.concatenate(idx), tuple(phases),
    )


def trajectory_dict(timed: PlanSamples, robot: str, planner: str, scene: str) -> dict[str, Any]:
    """The JSON form (``docs/trajectory.schema.json``)."""
    return {
        "format": FORMAT,
        "version": VERSION,
        "robot": robot,
        "scene": scene,
        "planner": planner,
        "joint_names": list(timed.joint_names),
        "rate_hz": timed.rate_hz,
        "duration_s": timed.duration_s,
        "phases": [
            {
                "index": p.index, "t_start_s": p.t_start, "t_end_s": p.t_end, "action_index": p.action_index,
                "action": p.action, "arm": p.arm, "held": p.held, "grasp": p.grasp, "release": p.release,
                "drives_drawer": p.drives_drawer,
            }
            for p in timed.phases
        ],
        "samples": {
            "t_s": [round(float(x), 6) for x in timed.t],
            "phase": [int(x) for x in timed.phase],
            "q": np.round(timed.q, 6).tolist(),
            "dq": np.round(timed.dq, 6).tolist(),
        },
    }
