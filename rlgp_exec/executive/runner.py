"""``rlgp-exec run``: connect to a robot through a HAL backend, run one task with the executive, record it.

Backends: ``sim`` (in-process PyBullet robot, stepped in lock-step; objects sensed from the simulation),
``zenoh`` (a robot — or ``rlgp-exec sim-robot`` — over Zenoh; object poses from a mocap topic), ``can``
(the HSR's CANopen drives; no object sensing on that bus: poses come from the scene file and the result
says the goal was not verified).
"""

from __future__ import annotations

import logging
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.executive import Executive, TaskResult
from rlgp_exec.executive.recorder import Recorder
from rlgp_exec.executive.world import ObjectSource, ScenePoses, SimMocap, ZenohMocap
from rlgp_exec.hal import make_backend
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.scene import Scene

__all__ = ["RunOptions", "connect", "run_task"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class RunOptions:
    backend: str = "sim"
    planner: str = "rlgp"
    record: Path | None = None
    endpoint: str | None = None  # zenoh
    namespace: str = ""  # zenoh
    zenoh_config: Path | None = None  # zenoh: json5 (TLS certificates, access control)
    can_interface: str = "virtual"
    can_channel: str = "rlgp"
    connect_timeout_s: float = 10.0
    heartbeat_timeout_s: float = 0.15  # zenoh/can: no fresh state for this long -> FAULT (15 cycles at 100 Hz)
    seed: int = 0


def connect(scene: Scene, opts: RunOptions) -> tuple[RobotInterface, ObjectSource]:
    """A configured HAL backend for ``scene``'s robot (robot alive) and the object source that goes with it."""
    options: dict[str, Any] = {}
    if opts.backend == "sim":
        options["scene"] = scene
    else:
        options["heartbeat_timeout"] = opts.heartbeat_timeout_s
    if opts.backend == "zenoh":
        if opts.endpoint:
            options["endpoint"] = opts.endpoint
        options["namespace"] = opts.namespace
        if opts.zenoh_config is not None:
            options["config_file"] = str(opts.zenoh_config)
    elif opts.backend == "can":
        options.update(interface=opts.can_interface, channel=opts.can_channel)
    hal = make_backend(opts.backend, scene.robot.name, **options)
    hal.configure()
    try:
        if opts.backend == "sim":
            return hal, SimMocap(hal)
        end = time.monotonic() + opts.connect_timeout_s
        while not hal.heartbeat_ok():
            if time.monotonic() > end:
                raise RlgpError(f"{opts.backend}: no robot heartbeat within {opts.connect_timeout_s} s")
            time.sleep(0.05)
        if opts.backend == "zenoh":
            return hal, ZenohMocap(hal.session, opts.namespace)  # type: ignore[attr-defined]
        return hal, ScenePoses(scene)
    except BaseException:
        hal.shutdown()
        raise


def run_task(scene: Scene, opts: RunOptions, goal: list[str] | None = None) -> tuple[TaskResult, Executive]:
    """Connect, run the scene's task (or ``goal``), bring the robot to rest and disconnect."""
    with ExitStack() as stack:
        recorder = stack.enter_context(Recorder(opts.record)) if opts.record else None
        hal, objects = connect(scene, opts)
        stack.callback(hal.shutdown)
        stack.callback(objects.close)
        if opts.backend == "zenoh":  # give the mocap stream a moment to arrive
            end = time.monotonic() + 2.0
            while not objects.poses() and time.monotonic() < end:
                time.sleep(0.05)
        ex = Executive(hal, scene, objects, planner=opts.planner, recorder=recorder, seed=opts.seed)
        return ex.run(goal), ex
    raise AssertionError("unreachable")
