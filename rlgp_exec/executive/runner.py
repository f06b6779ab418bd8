"""``rlgp-exec run``: connect to a robot through a HAL backend, run one task with the executive, record it.

Backends: ``sim`` (in-process PyBullet robot, stepped in lock-step; objects sensed from the simulation),
``zenoh`` (a robot — or ``rlgp-exec sim-robot --camera`` — over Zenoh; object poses from the robot's head
camera by default, or a mocap topic), ``can`` (the HSR's CANopen drives; no object sensing on that bus:
poses come from the scene file and the result says the goal was not verified).

``RunOptions.objects`` chooses the object source: ``camera`` (zenoh: AprilTags in the head camera's
images, :class:`~rlgp_exec.executive.camera_source.CameraObjects`), ``mocap`` (zenoh: ``ZenohMocap``;
sim: the simulation's truth), ``file`` (the scene file's poses, sensing nothing), or None for the
backend's default (sim: its truth, zenoh: camera, can: file). ``RunOptions.camera`` and ``calibration``
put a local camera (an OpenCV device or video file) in place of the robot's camera topics. With the
robot's camera in the loop, the recording and the live view also get its images, thinned to
``RunOptions.camera_record_hz`` (:class:`~rlgp_exec.executive.camera_record.CameraTap`).
"""

from __future__ import annotations

import logging
import re
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.camera_record import DEFAULT_RATE_HZ, CameraTap, LocalFrameTap
from rlgp_exec.executive.camera_source import CameraObjects
from rlgp_exec.executive.executive import Executive, TaskResult
from rlgp_exec.executive.foxglove_live import FoxgloveLive, Tee
from rlgp_exec.executive.local_camera import LocalCamera, check_source
from rlgp_exec.executive.recorder import Recorder, RecordSink
from rlgp_exec.executive.world import ObjectSource, ScenePoses, SimMocap, ZenohMocap
from rlgp_exec.hal import make_backend
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.perception.calibration import load_calibration
from rlgp_exec.planning.limits import DEFAULT_LIMITS, PlanLimits
from rlgp_exec.scene import Scene

__all__ = ["OBJECT_SOURCES", "RunOptions", "connect", "goal_objects", "object_source_name", "record_camera", "run_task"]

log = logging.getLogger(__name__)
OBJECT_SOURCES = ("camera", "mocap", "file")
_DEFAULT_SOURCE = {"sim": "mocap", "zenoh": "camera", "can": "file"}


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
    objects: str | None = None  # one of OBJECT_SOURCES; None: the backend's default
    limits: PlanLimits = DEFAULT_LIMITS  # the planner's CPU-time budget and search expansions, every plan
    foxglove: int | None = None  # serve the run live to Foxglove on this port (None: not)
    camera: str | None = None  # camera objects from a local device or video file, not the robot's topics
    calibration: Path | None = None  # ... with its OpenCV or ROS calibration file
    camera_record_hz: float = DEFAULT_RATE_HZ  # [Hz] camera images recorded and served (robot clock); 0: none


def object_source_name(opts: RunOptions) -> str:
    """The object source ``opts`` asks for, checked against what its backend can sense."""
    name = opts.objects or _DEFAULT_SOURCE.get(opts.backend, "file")
    if name not in OBJECT_SOURCES:
        raise RlgpError(f"--objects {name!r}: valid: {list(OBJECT_SOURCES)}")
    if name == "camera" and opts.backend != "zenoh":
        raise RlgpError(f"--objects camera reads the robot's camera over zenoh, not the {opts.backend} backend")
    if (opts.camera is None) != (opts.calibration is None):
        raise RlgpError("--camera and --calibration go together: a local camera needs its calibration file")
    if opts.camera is not None and name != "camera":
        raise RlgpError(f"--camera {opts.camera} is an object source: it needs --objects camera, not {name}")
    if opts.camera is not None and opts.calibration is not None:  # before connecting: refused at once

        check_source(opts.camera)
        load_calibration(opts.calibration)
    if name == "mocap" and opts.backend == "can":
        raise RlgpError("--objects mocap: the can backend has no motion-capture stream; use zenoh or file")
    return name


def goal_objects(scene: Scene, goal: list[str] | None = None) -> list[str]:
    """The objects of ``scene`` that ``goal`` (default: the scene's goal) names."""
    text = " ".join(goal) if goal is not None else " ".join(str(g) for g in scene.goal.literals)
    words = set(re.findall(r"[^\s()]+", text))
    return [o.name for o in scene.objects if o.name in words]


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
    source = object_source_name(opts)
    hal = make_backend(opts.backend, scene.robot.name, **options)
    hal.configure()
    try:
        if source == "file":
            return hal, ScenePoses(scene)
        if opts.backend == "sim":
            return hal, SimMocap(hal)
        end = time.monotonic() + opts.connect_timeout_s
        while not hal.heartbeat_ok():
            if time.monotonic() > end:
                raise RlgpError(f"{opts.backend}: no robot heartbeat within {opts.connect_timeout_s} s")
            time.sleep(0.05)
        if source == "camera":
            local = opts.camera is not None
            cam = CameraObjects(hal.session, hal.keys, hal.model, scene, images=not local)  # type: ignore[attr-defined]
            if local:
                assert opts.camera is not None and opts.calibration is not None
                try:
                    cam.feeds.append(LocalCamera(opts.camera, opts.calibration, cam).start())
                except BaseException:
                    cam.close()
                    raise
            return hal, cam
        return hal, ZenohMocap(hal.session, opts.namespace)  # type: ignore[attr-defined]
    except BaseException:
        hal.shutdown()
        raise


def _with_live_view(stack: ExitStack, recorder: Recorder | None, port: int | None) -> RecordSink | None:
    """The recorder, and the Foxglove live view on ``port`` if one is asked for (closed with ``stack``)."""
    if port is None:
        return recorder

    live = stack.enter_context(FoxgloveLive(port))
    log.info("live view: connect Foxglove to %s", live.url)
    return live if recorder is None else Tee(recorder, live)


def record_camera(stack: ExitStack, sink: RecordSink, hal: Any, objects: ObjectSource, opts: RunOptions) -> None:
    """The camera's frames into the recording and live view: a local camera's as it reads them, else the
    robot's camera topics through a CameraTap (closed before the recorder: entered after it)."""
    feeds = [f for f in getattr(objects, "feeds", []) if isinstance(f, LocalCamera)]
    if feeds:
        c = feeds[0].undistort.intrinsics
        feeds[0].on_frame = LocalFrameTap(sink, hal.keys, c.K, (c.width, c.height), opts.camera_record_hz)
        stack.callback(setattr, feeds[0], "on_frame", None)
        return
    tap = CameraTap(sink, hal.session, hal.keys, opts.camera_record_hz)
    stack.callback(tap.close)


def run_task(scene: Scene, opts: RunOptions, goal: list[str] | None = None) -> tuple[TaskResult, Executive]:
    """Connect, run the scene's task (or ``goal``), bring the robot to rest and disconnect."""
    with ExitStack() as stack:
        recorder = stack.enter_context(Recorder(opts.record)) if opts.record else None
        sink = _with_live_view(stack, recorder, opts.foxglove)
        hal, objects = connect(scene, opts)
        stack.callback(hal.shutdown)
        stack.callback(objects.close)
        if sink is not None and opts.camera_record_hz > 0 and object_source_name(opts) == "camera":
            record_camera(stack, sink, hal, objects, opts)
        if isinstance(objects, ZenohMocap):  # give the mocap stream a moment to arrive
            end = time.monotonic() + 2.0
            while not objects.poses() and time.monotonic() < end:
                time.sleep(0.05)
        ex = Executive(hal, scene, objects, planner=opts.planner, recorder=sink, seed=opts.seed,
                      limits=opts.limits)
        return ex.run(goal), ex
    raise AssertionError("unreachable")
