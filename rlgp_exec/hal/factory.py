"""``make_backend``: one place that maps a backend name to its :class:`RobotInterface`."""

from __future__ import annotations

from typing import Any

from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import HalError
from rlgp_exec.hal.zenoh_backend import ZenohBackend

__all__ = ["BACKENDS", "make_backend"]

BACKENDS: tuple[str, ...] = ("sim", "zenoh", "can")


def make_backend(name: str, robot: str = "hsr", **options: Any) -> RobotInterface:
    """A new, UNCONFIGURED backend.

    ``sim``: scene=Scene|None, dt; ``zenoh``: endpoint, namespace, control_period; ``can``: bus (a python-can
    bus) or interface/channel, sdo_timeout. All take heartbeat_timeout [s]. Unknown options raise.
    """
    cls: type[RobotInterface]
    if name == "sim":
        # local: a backend's library (PyBullet, python-can) loads only when that backend is made
        from rlgp_exec.hal.sim_backend import SimBackend

        cls = SimBackend
    elif name == "zenoh":
        cls = ZenohBackend
    elif name == "can":
        # local: a backend's library (PyBullet, python-can) loads only when that backend is made
        from rlgp_exec.hal.can_backend import CanBackend

        cls = CanBackend
    else:
        raise HalError(f"unknown HAL backend {name!r}; valid: {list(BACKENDS)}")
    try:
        return cls(robot, **options)
    except TypeError as e:
        raise HalError(f"HAL backend {name!r}: bad options {sorted(options)}: {e}") from e
