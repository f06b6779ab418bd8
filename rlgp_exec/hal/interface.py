"""``RobotInterface``: the abstract HAL every backend (sim, zenoh, can) implements.

Lifecycle (ros2_control-like)::

    UNCONFIGURED --configure()--> INACTIVE --activate()--> ACTIVE --deactivate()--> INACTIVE
    INACTIVE/ACTIVE --estop()--> ESTOPPED --rearm()--> INACTIVE (activate() again to move)
    any --shutdown()--> FINALIZED;  a transport failure --> ERROR

Commands are checked here, once, for every backend: lifecycle, e-stop, heartbeat (never move on
stale state) and limits. Only then does the backend put them on its wire. The robot side checks
them again (see the servers): a client bug cannot move the robot out of its limits.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike

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
from rlgp_exec.hal.validate import CommandLimits, RejectCounter
from rlgp_exec.robot import RobotModel

__all__ = ["RobotInterface"]

log = logging.getLogger(__name__)


class RobotInterface(abc.ABC):
    """A robot seen through one transport. Subclasses implement the ``_on_*``/``_send_*`` hooks."""

    backend: str = "abstract"

    def __init__(self, model: RobotModel, heartbeat_timeout: float = 0.25) -> None:
        if not heartbeat_timeout > 0.0:
            raise HalError(f"heartbeat_timeout must be > 0 s, got {heartbeat_timeout}")
        self.model = model
        self.limits = CommandLimits(model)
        self.joint_names: tuple[str, ...] = self.limits.names  # reported in RobotState
        self.setpoint_names: tuple[str, ...] = self.limits.setpoint_names  # commanded by write_setpoint
        self.heartbeat_timeout = float(heartbeat_timeout)
        self.rejects = RejectCounter(f"hal[{self.backend}] incoming")  # bad payloads from the robot
        self.refused = RejectCounter(f"hal[{self.backend}] outgoing")  # commands refused before sending
        self._lifecycle = Lifecycle.UNCONFIGURED

    # ------------------------------------------------------------------ lifecycle
    @property
    def lifecycle(self) -> Lifecycle:
        return self._lifecycle

    def _require(self, action: str, *allowed: Lifecycle) -> None:
        if self._lifecycle not in allowed:
            raise HalError(
                f"{self.backend}: cannot {action} in state {self._lifecycle.name}; "
                f"allowed from {[a.name for a in allowed]}"
            )

    def configure(self) -> None:
        """Open the transport and start receiving state."""
        self._require("configure", Lifecycle.UNCONFIGURED)
        try:
            self._on_configure()
        except HalError:
            self._lifecycle = Lifecycle.ERROR
            raise
        except Exception as e:
            self._lifecycle = Lifecycle.ERROR
            raise HalError(f"{self.backend}: configure failed: {type(e).__name__}: {e}") from e
        self._lifecycle = Lifecycle.INACTIVE
        log.info("%s: configured", self.backend)

    def activate(self) -> None:
        """Start accepting commands. Needs a live robot (heartbeat) that is not e-stopped."""
        self._require("activate", Lifecycle.INACTIVE)
        if not self.heartbeat_ok():
            raise HalError(
                f"{self.backend}: cannot activate: no heartbeat from the robot within {self.heartbeat_timeout} s"
            )
        self._on_activate()
        self._lifecycle = Lifecycle.ACTIVE
        log.info("%s: active", self.backend)

    def deactivate(self) -> None:
        """Stop accepting commands; the robot holds its position and the base stops."""
        self._require("deactivate", Lifecycle.ACTIVE)
        self._hold()
        self._lifecycle = Lifecycle.INACTIVE

    def shutdown(self) -> None:
        if self._lifecycle is Lifecycle.FINALIZED:
            return
        if self._lifecycle is Lifecycle.ACTIVE:
            self._hold()
        try:
            self._on_shutdown()
        finally:
            self._lifecycle = Lifecycle.FINALIZED

    def __enter__(self) -> RobotInterface:
        return self

    def __exit__(self, *exc: object) -> None:
        self.shutdown()

    # ------------------------------------------------------------------ state
    def read_state(self) -> RobotState | None:
        """The latest state received from the robot, or None before the first one."""
        self._require("read state", Lifecycle.INACTIVE, Lifecycle.ACTIVE, Lifecycle.ESTOPPED)
        return self._latest_state()

    @abc.abstractmethod
    def heartbeat_ok(self) -> bool:
        """True while the robot is alive: fresh state within ``heartbeat_timeout`` and present."""

    # ------------------------------------------------------------------ commands
    def _gate(self) -> CommandResult:
        if self._lifecycle is Lifecycle.ESTOPPED:
            return CommandResult(CommandStatus.ESTOPPED, "e-stop latched; rearm() and activate() first")
        if self._lifecycle is not Lifecycle.ACTIVE:
            return CommandResult(CommandStatus.NOT_ACTIVE, f"lifecycle is {self._lifecycle.name}, not ACTIVE")
        if not self.heartbeat_ok():
            return CommandResult(CommandStatus.STALE_STATE, f"no robot heartbeat within {self.heartbeat_timeout} s")
        st = self._latest_state()
        if st is not None and st.estopped:
            return CommandResult(CommandStatus.ESTOPPED, "the robot reports its run-stop/e-stop engaged")
        return CommandResult(CommandStatus.OK)

    def _refuse(self, res: CommandResult, what: str) -> CommandResult:
        self.refused.reject(res.status.value, f"{what}: {res.reason}")
        return res

    def write_setpoint(
        self, q: ArrayLike, dq: ArrayLike | None = None, names: Sequence[str] | None = None
    ) -> CommandResult:
        """Command joint positions ``q`` [m|rad] with feed-forward velocities ``dq`` for ``names``
        (default: all of :attr:`setpoint_names`, i.e. every joint but the base and the gripper)."""
        names = tuple(self.setpoint_names if names is None else names)
        self.limits.indices(names)  # unknown names are misuse: HalError
        sp = JointSetpoint(names, np.asarray(q, dtype=float), None if dq is None else np.asarray(dq, dtype=float))
        res = self._gate()
        if not res:
            return self._refuse(res, "setpoint")
        reason = self.limits.check_setpoint(sp)
        if reason:
            return self._refuse(CommandResult(CommandStatus.INVALID, reason), "setpoint")
        self._send_setpoint(sp)
        return res

    def write_base_velocity(self, vx: float, vy: float, wz: float) -> CommandResult:
        """Command the base twist in the base frame: vx, vy [m/s], wz [rad/s]."""
        res = self._gate()
        if not res:
            return self._refuse(res, "base velocity")
        reason = self.limits.check_base_velocity(vx, vy, wz)
        if reason:
            return self._refuse(CommandResult(CommandStatus.INVALID, reason), "base velocity")
        self._send_base_velocity(float(vx), float(vy), float(wz))
        return res

    def gripper(self, cmd: GripperCommand) -> CommandResult:
        res = self._gate()
        if not res:
            return self._refuse(res, "gripper")
        if cmd.action is GripperAction.GRASP:
            reason = self.limits.check_grasp_force(cmd.force)
            if reason:
                return self._refuse(CommandResult(CommandStatus.INVALID, reason), "gripper")
        self._send_gripper(cmd)
        return res

    def estop(self) -> CommandResult:
        """Latch the e-stop: the robot holds, the base stops, commands are refused until rearm()."""
        self._require("estop", Lifecycle.INACTIVE, Lifecycle.ACTIVE, Lifecycle.ESTOPPED)
        self._send_estop(True)
        self._lifecycle = Lifecycle.ESTOPPED
        log.warning("%s: e-stop latched", self.backend)
        return CommandResult(CommandStatus.OK)

    def rearm(self) -> CommandResult:
        """Release our e-stop; back to INACTIVE (call activate() to move again)."""
        self._require("rearm", Lifecycle.ESTOPPED)
        self._send_estop(False)
        self._lifecycle = Lifecycle.INACTIVE
        log.info("%s: e-stop released", self.backend)
        return CommandResult(CommandStatus.OK)

    def estop_status(self) -> EstopStatus:
        """Whether our e-stop is commanded and the robot's state confirms it. A backend that re-sends an
        unconfirmed e-stop counts its re-sends; this default (no re-sending) reads the latest state."""
        engaged = self._lifecycle is Lifecycle.ESTOPPED
        st = self._latest_state() if engaged else None
        return EstopStatus(engaged, st is not None and st.estopped, 0)

    def _hold(self) -> None:
        st = self._latest_state()
        if st is not None and self.heartbeat_ok():
            self._send_setpoint(JointSetpoint(self.setpoint_names, st.positions(self.setpoint_names)))
        self._send_base_velocity(0.0, 0.0, 0.0)

    # ------------------------------------------------------------------ backend hooks
    @abc.abstractmethod
    def _on_configure(self) -> None: ...

    def _on_activate(self) -> None:  # noqa: B027 - optional hook
        pass

    @abc.abstractmethod
    def _on_shutdown(self) -> None: ...

    @abc.abstractmethod
    def _latest_state(self) -> RobotState | None: ...

    @abc.abstractmethod
    def _send_setpoint(self, sp: JointSetpoint) -> None: ...

    @abc.abstractmethod
    def _send_base_velocity(self, vx: float, vy: float, wz: float) -> None: ...

    @abc.abstractmethod
    def _send_gripper(self, cmd: GripperCommand) -> None: ...

    @abc.abstractmethod
    def _send_estop(self, engaged: bool) -> None: ...
