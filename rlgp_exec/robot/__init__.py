"""Robot models: one ``RobotModel`` per robot (pinocchio, CasADi FK, limits, PyBullet body)."""

from rlgp_exec.robot.config import BASE_JOINTS, Manipulator, RobotConfig, load_robot_config
from rlgp_exec.robot.limits import JointLimits, wrap_angle
from rlgp_exec.robot.model import RobotModel, load_robot

__all__ = [
    "BASE_JOINTS",
    "JointLimits",
    "Manipulator",
    "RobotConfig",
    "RobotModel",
    "load_robot",
    "load_robot_config",
    "wrap_angle",
]
