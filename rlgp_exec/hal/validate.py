"""Checks shared by the HAL clients and the robot servers: setpoint/velocity limits and reject counting.

Every backend checks commands before they leave (client side) and every server checks them again when
they arrive (robot side): a bad payload is rejected, counted under a short reason key, logged with the
full reason, and never moves anything.
"""

from __future__ import annotations

import logging
import threading
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from rlgp_exec.hal.types import HalError, JointSetpoint
from rlgp_exec.robot import RobotModel

__all__ = ["MAX_GRASP_FORCE", "CommandLimits", "RejectCounter", "command_joints", "guarded"]

log = logging.getLogger(__name__)

MAX_GRASP_FORCE = 50.0  # [N]
_POS_TOL = 1e-6  # [m] or [rad] slack on position limits
_VEL_SLACK = 1.05  # setpoint velocities may exceed the URDF limit by 5 % (tracking headroom)


def command_joints(model: RobotModel) -> tuple[str, ...]:
    """The joints a backend reports and commands: every joint of q except the planar base."""
    return tuple(model.joint_names[3:])


class RejectCounter:
    """Thread-safe counts of rejected inputs by reason key; logs the first few of each key at WARNING."""

    def __init__(self, what: str, warn_first: int = 3) -> None:
        self.what = what
        self._warn_first = warn_first
        self._counts: Counter[str] = Counter()
        self._last: str = ""
        self._lock = threading.Lock()

    def reject(self, key: str, reason: str) -> None:
        with self._lock:
            self._counts[key] += 1
            n = self._counts[key]
            self._last = f"{key}: {reason}"
        if n <= self._warn_first:
            log.warning("%s: rejected (%s): %s", self.what, key, reason)
        else:
            log.debug("%s: rejected (%s, #%d): %s", self.what, key, n, reason)

    @property
    def total(self) -> int:
        with self._lock:
            return sum(self._counts.values())

    @property
    def last(self) -> str:
        with self._lock:
            return self._last

    def counts(self) -> dict[str, int]:
        with self._lock:
            return dict(self._counts)


def guarded(
    rejects: RejectCounter, topic: str, fn: Callable[[bytes], None], key: str | None = None
) -> Callable[[Any], None]:
    """A Zenoh subscriber callback handing ``fn`` the sample's bytes; an exception in it is counted under
    "internal" instead of ending the subscriber. With ``key``, a sample on any other key expression (a
    wildcard put that intersects it) is counted under "wildcard" and dropped."""

    def cb(sample: Any) -> None:
        if key is not None and str(sample.key_expr) != key:
            rejects.reject("wildcard", f"{topic}: a sample on {sample.key_expr}, not exactly {key}")
            return
        try:
            fn(sample.payload.to_bytes())
        except Exception as e:  # a payload must never kill the subscriber
            rejects.reject("internal", f"{topic}: {type(e).__name__}: {e}")

    return cb


class CommandLimits:
    """Position/velocity limits of a robot's commanded joints and base, from its RobotModel."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self.names = command_joints(model)
        self._index = {n: i for i, n in enumerate(self.names)}
        lim = model.limits.subset(self.names)
        self.lower, self.upper, self.velocity = lim.lower, lim.upper, lim.velocity
        self.base_velocity = np.asarray(model.limits.velocity[:3], dtype=float)
        grippers = {model.joint_names[i] for m in model.config.manipulators for i in model.group(m.gripper)}
        self.gripper_joint = model.joint_names[model.group(model.manipulator().gripper)[0]]
        #: joints commanded by setpoints: all but the base and the grippers (those take gripper())
        self.setpoint_names = tuple(n for n in self.names if n not in grippers)
        self._gripper_names = grippers

    def indices(self, names: Sequence[str]) -> list[int]:
        missing = [n for n in names if n not in self._index]
        if missing:
            raise HalError(f"{self.model.name}: unknown joint(s) {missing}; valid: {list(self.names)}")
        return [self._index[n] for n in names]

    def check_setpoint(self, sp: JointSetpoint) -> str:
        """'' when ``sp`` is acceptable, else the reason (names known, finite, within limits)."""
        unknown = [n for n in sp.names if n not in self._index]
        if unknown:
            return f"unknown joint(s) {unknown}; valid: {list(self.names)}"
        if not sp.names:
            return "no joints in the setpoint"
        grip = [n for n in sp.names if n in self._gripper_names]
        if grip:
            return f"gripper joint(s) {grip} are commanded with gripper(), not setpoints"
        if not (np.all(np.isfinite(sp.q)) and np.all(np.isfinite(sp.dq))):
            bad = [n for n, a, b in zip(sp.names, sp.q, sp.dq, strict=True) if not (np.isfinite(a) and np.isfinite(b))]
            return f"non-finite position/velocity for {bad}"
        idx = [self._index[n] for n in sp.names]
        lo, hi, vmax = self.lower[idx], self.upper[idx], self.velocity[idx]
        out = [
            f"{n}={v:.4f} not in [{a:.4f}, {b:.4f}]"
            for n, v, a, b in zip(sp.names, sp.q, lo, hi, strict=True)
            if not (a - _POS_TOL <= v <= b + _POS_TOL)
        ]
        if out:
            return "position out of limits: " + ", ".join(out)
        fast = [
            f"|{n}'|={abs(v):.3f} > {m:.3f}"
            for n, v, m in zip(sp.names, sp.dq, vmax, strict=True)
            if abs(v) > m * _VEL_SLACK
        ]
        if fast:
            return "velocity over limit: " + ", ".join(fast)
        return ""

    def check_base_velocity(self, vx: float, vy: float, wz: float) -> str:
        v = np.array([vx, vy, wz], dtype=float)
        if not np.all(np.isfinite(v)):
            return f"non-finite base velocity {v.tolist()}"
        over = np.abs(v) > self.base_velocity * _VEL_SLACK
        if over.any():
            names = np.array(["vx", "vy", "wz"])[over].tolist()
            return f"base velocity over limit for {names}: {v.tolist()} vs {self.base_velocity.tolist()}"
        return ""

    @staticmethod
    def check_grasp_force(force: float) -> str:
        if not (np.isfinite(force) and 0.0 < force <= MAX_GRASP_FORCE):
            return f"grasp force {force} N not in (0, {MAX_GRASP_FORCE}]"
        return ""
