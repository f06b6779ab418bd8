"""Execution monitors: each checks one thing every control cycle (or before a segment) and, when it is
violated, says what to do about it.

- start state: before a segment, the measured configuration must be within tolerance of the segment's
  first waypoint (wrap-aware on continuous joints) -> REPLAN from where the robot is.
- tracking: commanded vs measured joints (and base) -> STOP (safe stop, then replan).
- duration: a segment may take at most ``DURATION_SCALE`` x its planned duration plus ``DURATION_MARGIN_S``
  (MoveIt's convention: 1.1x plus a margin) -> STOP.
- staleness: no fresh robot state (the HAL's heartbeat) -> FAULT; nothing can be commanded.
- robot faults: the robot reports a fault (EMCY, watchdog, lost executive) -> FAULT.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

import numpy as np

from rlgp_exec.robot.model import FloatArray, RobotModel

__all__ = [
    "DURATION_MARGIN_S",
    "DURATION_SCALE",
    "Reaction",
    "Tolerances",
    "Violation",
    "check_duration",
    "check_start_state",
    "check_tracking",
    "joint_error",
]

DURATION_SCALE = 1.1
DURATION_MARGIN_S = 0.5


class Reaction(enum.Enum):
    REPLAN = "replan"  # stop where we are (already at rest) and plan again from the current state
    STOP = "stop"  # jerk-limited stop, then replan
    FAULT = "fault"  # hold; a person has to look (or the robot is gone)


@dataclass(frozen=True)
class Violation:
    monitor: str  # "start_state" | "tracking" | "duration" | "stale_state" | "robot_fault" | ...
    reaction: Reaction
    detail: str

    def __str__(self) -> str:
        return f"{self.monitor}: {self.detail} -> {self.reaction.value}"


@dataclass(frozen=True)
class Tolerances:
    start_joint: float = 0.05  # [rad | m] arm joints, start of a segment
    start_base_xy: float = 0.05  # [m]
    start_base_yaw: float = 0.08  # [rad]
    track_joint: float = 0.15  # [rad | m] commanded - measured, during a segment
    track_base_xy: float = 0.10  # [m]
    track_base_yaw: float = 0.20  # [rad]
    object_moved: float = 0.02  # [m] sensed vs planned, every object the plan has not grasped yet


def joint_error(model: RobotModel, q_a: FloatArray, q_b: FloatArray) -> FloatArray:
    """|q_a - q_b| per joint (nq,), wrapped to [-pi, pi] on continuous joints and the base yaw."""
    d = np.asarray(q_a, float) - np.asarray(q_b, float)
    for i in np.flatnonzero(model.limits.continuous):
        d[i] = math.remainder(d[i], 2 * math.pi)
    d[2] = math.remainder(d[2], 2 * math.pi)
    return np.abs(d)


def _worst(model: RobotModel, err: FloatArray, xy: float, yaw: float, joint: float) -> str | None:
    if math.hypot(err[0], err[1]) > xy:
        return f"base position off by {math.hypot(err[0], err[1]):.3f} m (tolerance {xy} m)"
    if err[2] > yaw:
        return f"base yaw off by {err[2]:.3f} rad (tolerance {yaw} rad)"
    arm = err[3:]
    if arm.size and arm.max() > joint:
        i = 3 + int(arm.argmax())
        return f"{model.joint_names[i]} off by {err[i]:.3f} (tolerance {joint})"
    return None


def _masked(model: RobotModel, q_a: FloatArray, q_b: FloatArray, joints: FloatArray | None) -> FloatArray:
    err = joint_error(model, q_a, q_b)
    if joints is None:
        return err
    mask = np.zeros(model.nq, bool)
    mask[joints] = True
    return np.where(mask, err, 0.0)


def check_start_state(
    model: RobotModel, q_measured: FloatArray, q_start: FloatArray, tol: Tolerances, joints: FloatArray | None = None
) -> Violation | None:
    """Is the robot where the segment starts? ``joints``: indices to compare (default all)."""
    err = _masked(model, q_measured, q_start, joints)
    why = _worst(model, err, tol.start_base_xy, tol.start_base_yaw, tol.start_joint)
    return None if why is None else Violation("start_state", Reaction.REPLAN, why)


def check_tracking(
    model: RobotModel,
    q_measured: FloatArray,
    q_commanded: FloatArray,
    tol: Tolerances,
    joints: FloatArray | None = None,
) -> Violation | None:
    """Does the robot follow? Commanded vs measured, on ``joints`` (default all)."""
    err = _masked(model, q_measured, q_commanded, joints)
    why = _worst(model, err, tol.track_base_xy, tol.track_base_yaw, tol.track_joint)
    return None if why is None else Violation("tracking", Reaction.STOP, why)


def check_duration(elapsed_s: float, planned_s: float) -> Violation | None:
    allowed = DURATION_SCALE * planned_s + DURATION_MARGIN_S
    if elapsed_s > allowed:
        return Violation(
            "duration",
            Reaction.STOP,
            f"segment running {elapsed_s:.2f} s, planned {planned_s:.2f} s (allowed {allowed:.2f} s)",
        )
    return None
