"""Hardware abstraction: one ``RobotInterface`` over three backends -- in-process PyBullet (``sim``), the
robot's ROS 2 topics through Zenoh (``zenoh``) and its CANopen drives (``can``). See ``make_backend``."""

from rlgp_exec.hal.factory import BACKENDS, make_backend
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import (
    CommandResult,
    CommandStatus,
    EstopStatus,
    GripperAction,
    GripperCommand,
    HalError,
    JointSetpoint,
    Lifecycle,
    RobotState,
)

__all__ = [
    "BACKENDS",
    "CommandResult",
    "CommandStatus",
    "EstopStatus",
    "GripperAction",
    "GripperCommand",
    "HalError",
    "JointSetpoint",
    "Lifecycle",
    "RobotInterface",
    "RobotState",
    "make_backend",
]
