"""HAL value types: lifecycle states, robot state, setpoints, gripper commands, statuses and errors.

Units are SI everywhere: [s], [m], [rad], [m/s], [rad/s], [N]. Joint vectors are ordered by the
``names`` that travel with them; the planar base is never part of a joint vector (it has its own
pose x, y, yaw in the world/odometry frame and is commanded by velocity in the base frame).
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rlgp_exec.errors import RlgpError

__all__ = [
    "CommandResult",
    "CommandStatus",
    "EstopStatus",
    "GripperAction",
    "GripperCommand",
    "HalError",
    "JointSetpoint",
    "Lifecycle",
    "RobotState",
    "frozen_array",
]

FloatArray = NDArray[np.float64]


class HalError(RlgpError):
    """A real error in the HAL: misuse (wrong lifecycle order, unknown joint, bad shape), a backend that
    cannot be built or a transport that cannot be opened. Rejected commands are :class:`CommandStatus`."""


class Lifecycle(enum.Enum):
    """ros2_control-like hardware lifecycle."""

    UNCONFIGURED = "unconfigured"  # built, no transport open
    INACTIVE = "inactive"  # transport open, state readable, commands refused
    ACTIVE = "active"  # commands accepted
    ESTOPPED = "estopped"  # e-stop latched: motion held, commands refused until rearm()
    ERROR = "error"  # unrecoverable backend failure (transport died); shutdown() and rebuild
    FINALIZED = "finalized"  # shut down


class CommandStatus(enum.Enum):
    """Expected outcomes of a command: only OK means it was sent to the robot."""

    OK = "ok"
    NOT_ACTIVE = "not_active"  # lifecycle is not ACTIVE
    ESTOPPED = "estopped"  # the e-stop is latched (ours or the robot's run-stop)
    INVALID = "invalid"  # NaN/inf, out of the position/velocity limits
    STALE_STATE = "stale_state"  # the robot's heartbeat is lost: no motion on stale state


@dataclass(frozen=True)
class CommandResult:
    status: CommandStatus
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.status is CommandStatus.OK

    def __bool__(self) -> bool:
        return self.ok


@dataclass(frozen=True)
class EstopStatus:
    """Our e-stop as the robot's reported state confirms it."""

    engaged: bool  # commanded: estop() and no rearm() since
    confirmed: bool  # engaged, and the robot's latest state reports it engaged
    resends: int  # e-stop commands sent again because the robot's state did not confirm one (since configure)


def frozen_array(values: ArrayLike, n: int | None = None, what: str = "array") -> FloatArray:
    """A read-only float64 copy of ``values`` (checked to have ``n`` entries when given)."""
    a = np.array(values, dtype=float).reshape(-1)
    if n is not None and a.shape != (n,):
        raise HalError(f"{what}: expected {n} values, got {a.shape[0]}")
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False, init=False)
class RobotState:
    """One snapshot of the robot.

    ``stamp`` is the robot's clock [s] (sim time for the sim backend). ``names``/``q``/``dq`` cover the
    arm, head and gripper joints (not the base). ``base`` is (x [m], y [m], yaw [rad]) in the odometry
    frame. ``gripper`` is the gripper command joint position (HSR: hand_motor_joint [rad], larger =
    more open). ``faults`` are human-readable fault strings reported by the robot (EMCY, watchdogs).
    """

    stamp: float
    names: tuple[str, ...]
    q: FloatArray
    dq: FloatArray
    base: tuple[float, float, float]
    base_velocity: tuple[float, float, float]  # base frame vx, vy, wz
    gripper: float
    estopped: bool
    faults: tuple[str, ...]

    def __init__(
        self,
        stamp: float,
        names: Sequence[str],
        q: ArrayLike,
        dq: ArrayLike,
        base: Sequence[float] = (0.0, 0.0, 0.0),
        base_velocity: Sequence[float] = (0.0, 0.0, 0.0),
        gripper: float = 0.0,
        estopped: bool = False,
        faults: Sequence[str] = (),
    ) -> None:
        n = len(names)
        for k, v in (
            ("stamp", float(stamp)),
            ("names", tuple(names)),
            ("q", frozen_array(q, n, "RobotState.q")),
            ("dq", frozen_array(dq, n, "RobotState.dq")),
            ("base", tuple(float(b) for b in base)),
            ("base_velocity", tuple(float(b) for b in base_velocity)),
            ("gripper", float(gripper)),
            ("estopped", bool(estopped)),
            ("faults", tuple(faults)),
        ):
            object.__setattr__(self, k, v)

    def position(self, name: str) -> float:
        """Position of one joint; unknown names raise with the valid options."""
        try:
            return float(self.q[self.names.index(name)])
        except ValueError:
            raise HalError(f"RobotState has no joint {name!r}; valid: {list(self.names)}") from None

    def positions(self, names: Sequence[str]) -> FloatArray:
        return np.array([self.position(n) for n in names])

    def model_q(self, model_joint_names: Sequence[str]) -> FloatArray:
        """q in RobotModel order ([base_x, base_y, base_yaw, joints...]); joints missing here raise."""
        out = np.empty(len(model_joint_names))
        for i, n in enumerate(model_joint_names):
            if i < 3 and n in ("base_x", "base_y", "base_yaw"):
                out[i] = self.base[i]
            else:
                out[i] = self.position(n)
        return out


@dataclass(frozen=True, eq=False, init=False)
class JointSetpoint:
    """A position (and feed-forward velocity) setpoint for some joints, to be reached now."""

    names: tuple[str, ...]
    q: FloatArray
    dq: FloatArray

    def __init__(self, names: Sequence[str], q: ArrayLike, dq: ArrayLike | None = None) -> None:
        n = len(names)
        object.__setattr__(self, "names", tuple(names))
        object.__setattr__(self, "q", frozen_array(q, n, "JointSetpoint.q"))
        object.__setattr__(self, "dq", frozen_array(np.zeros(n) if dq is None else dq, n, "JointSetpoint.dq"))
        if len(set(self.names)) != n:
            raise HalError(f"JointSetpoint: duplicate joint names in {list(self.names)}")


class GripperAction(enum.Enum):
    OPEN = "open"  # go to the open position
    CLOSE = "close"  # go to the closed position (position control, no force limit semantics)
    GRASP = "grasp"  # close with a force limit; stops on the object


@dataclass(frozen=True)
class GripperCommand:
    action: GripperAction
    force: float = 0.0  # [N], GRASP only

    def __post_init__(self) -> None:
        if not isinstance(self.action, GripperAction):
            raise HalError(f"GripperCommand.action must be a GripperAction; valid: {[a.name for a in GripperAction]}")
        if self.action is GripperAction.GRASP and not (np.isfinite(self.force) and self.force > 0.0):
            raise HalError(f"GripperCommand GRASP needs a finite force > 0 [N], got {self.force}")

    @classmethod
    def open(cls) -> GripperCommand:
        return cls(GripperAction.OPEN)

    @classmethod
    def close(cls) -> GripperCommand:
        return cls(GripperAction.CLOSE)

    @classmethod
    def grasp(cls, force: float = 10.0) -> GripperCommand:
        return cls(GripperAction.GRASP, force)
