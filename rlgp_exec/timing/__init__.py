"""Trajectory timing: TOPPRA time-optimal parameterisation and Ruckig jerk-limited streaming."""

from rlgp_exec.timing.plan_timing import TimedPlan, to_trajectory
from rlgp_exec.timing.streamer import TRACKING_HEADROOM, Setpoint, Streamer, StreamMode, stop_time_bound
from rlgp_exec.timing.toppra_param import time_parameterize, time_parameterize_phases
from rlgp_exec.timing.trajectory import PhaseKind, Segment, TimingError, TimingResult, TimingStatus, Trajectory

__all__ = [
    "TRACKING_HEADROOM",
    "PhaseKind",
    "Segment",
    "Setpoint",
    "StreamMode",
    "Streamer",
    "TimedPlan",
    "TimingError",
    "TimingResult",
    "TimingStatus",
    "Trajectory",
    "stop_time_bound",
    "time_parameterize",
    "time_parameterize_phases",
    "to_trajectory",
]
