"""The ``sim`` backend: an in-process :class:`SimRobot`, stepped in lock-step by the caller.

Nothing moves unless :meth:`SimBackend.step` is called; commands take effect on the next step. The
heartbeat is the physics itself: if nobody has stepped it within ``heartbeat_timeout`` s of wall time,
the simulated robot counts as stalled (the loop driving it died) and :meth:`heartbeat_ok` is False.
"""

from __future__ import annotations

import logging
import time

from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.sim_physics import SimRobot
from rlgp_exec.hal.types import GripperCommand, HalError, JointSetpoint, RobotState
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import Scene

__all__ = ["SimBackend"]

log = logging.getLogger(__name__)


class SimBackend(RobotInterface):
    backend = "sim"

    def __init__(
        self, robot: str = "hsr", scene: Scene | None = None, dt: float = 0.005, heartbeat_timeout: float = 0.25
    ) -> None:
        name = scene.robot.name if scene is not None else robot
        super().__init__(load_robot(name), heartbeat_timeout)
        self._scene = scene
        self._dt = dt
        self.sim: SimRobot | None = None

    def _on_configure(self) -> None:
        self.sim = SimRobot(self.model.name, self._scene, dt=self._dt)

    def _on_shutdown(self) -> None:
        if self.sim is not None:
            self.sim.close()
            self.sim = None

    def _need_sim(self) -> SimRobot:
        if self.sim is None:
            raise HalError("sim: not configured; call configure() first")
        return self.sim

    def step(self, duration: float | None = None) -> RobotState:
        """Advance the physics by ``duration`` [s] (one physics step by default); the new state."""
        sim = self._need_sim()
        sim.step(duration)
        return sim.state()

    def heartbeat_ok(self) -> bool:
        return self.sim is not None and (time.monotonic() - self.sim.last_step_wall) <= self.heartbeat_timeout

    def _latest_state(self) -> RobotState | None:
        return None if self.sim is None else self.sim.state()

    def _send_setpoint(self, sp: JointSetpoint) -> None:
        self._need_sim().set_joint_targets(sp)

    def _send_base_velocity(self, vx: float, vy: float, wz: float) -> None:
        self._need_sim().set_base_velocity(vx, vy, wz)

    def _send_gripper(self, cmd: GripperCommand) -> None:
        self._need_sim().gripper(cmd)

    def _send_estop(self, engaged: bool) -> None:
        self._need_sim().estop(engaged)
