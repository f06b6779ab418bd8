"""A plan as the executive runs it: each moving phase timed by TOPPRA within the limits the streamer
tracks (``TRACKING_HEADROOM`` of the robot's), each gripper event between them left untimed."""

from __future__ import annotations

from dataclasses import dataclass

from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.validate import Phase
from rlgp_exec.robot import RobotModel, load_robot
from rlgp_exec.timing.streamer import TRACKING_HEADROOM
from rlgp_exec.timing.toppra_param import time_parameterize
from rlgp_exec.timing.trajectory import TimingError, Trajectory

__all__ = ["TimedPlan", "to_trajectory"]


@dataclass(frozen=True)
class TimedPlan:
    """A plan's phases and their trajectories, one per phase: None where the phase does not move (a
    grasp or release happens at its end)."""

    phases: tuple[Phase, ...]
    trajectories: tuple[Trajectory | None, ...]

    @property
    def duration_s(self) -> float:
        """The motion's total duration [s] (gripper events excluded)."""
        return sum(t.duration for t in self.trajectories if t is not None)


def to_trajectory(plan: Plan, robot: RobotModel | str, headroom: tuple[float, float] = TRACKING_HEADROOM) -> TimedPlan:
    """Time ``plan`` for ``robot`` (a model or "hsr"/"pr2") at ``headroom`` = (velocity, acceleration)
    fractions of its limits. A phase that cannot be timed raises TimingError naming it and why."""
    model = load_robot(robot) if isinstance(robot, str) else robot
    limits = model.limits.scaled(*headroom)
    out: list[Trajectory | None] = []
    for k, ph in enumerate(plan.phases):
        if len(ph.path) < 2:
            out.append(None)
            continue
        res = time_parameterize(ph.path, limits)
        if res.trajectory is None:
            raise TimingError(f"timing phase {k}: {res.status.value}: {res.reason}")
        out.append(res.trajectory)
    return TimedPlan(tuple(plan.phases), tuple(out))
