"""``rlgp-exec bench camera``: object sensing by the robot's head camera over the wire, measured.

A ``sim-robot`` process with its camera node (``RobotProcess(camera=True)``) on ``sorting_hsr``, the HAL
over Zenoh and :class:`~rlgp_exec.executive.camera_source.CameraObjects` on its session:

* standing: for ``seconds`` the HAL runs a 100 Hz control loop (read the state, command the hold pose,
  sleep to absolute deadlines) while images flow; every 0.2 s each sensed pose is compared with the
  simulation's truth (the server's mocap stream): ``pos_err_mm_median`` / ``_p95`` (with the objects'
  distances from the camera), ``latency_ms_p99`` (an image's stamp — the arrival of the joint state it
  was rendered at — to its world poses), ``frames_per_s`` (images received) and
  ``frames_processed_per_s``, ``loop_period_err_ms_p99`` (the HAL client's loop) and
  ``robot_loop_period_err_ms_p99`` (the robot server's own 100 Hz loop, from its stats);
* ``time_to_first_motion_s``: from the goal to the first setpoint of a fresh executive, sensing by
  camera included (its SENSE: ``look_for`` on the goal's objects; then PLAN and timing), split into the
  stages' times; the task is then cancelled.
"""

from __future__ import annotations

import json
import logging
import math
import os
import platform
import threading
import time
from pathlib import Path
from typing import Any

import numpy as np

from rlgp_exec.executive.act import ControlClock
from rlgp_exec.executive.camera_source import CameraObjects, LookResult
from rlgp_exec.executive.executive import Executive
from rlgp_exec.executive.runner import RunOptions, connect
from rlgp_exec.executive.world import ZenohMocap
from rlgp_exec.hal.realtime import realtime_priority
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.shipped import shipped_scene_path
from rlgp_exec.sim.robot_process import RobotProcess

__all__ = ["SCENE", "run_camera_bench"]

log = logging.getLogger(__name__)

SCENE = shipped_scene_path("sorting_hsr")


def _p(xs: list[float], q: float) -> float | None:
    return float(np.percentile(xs, q)) if xs else None


def _robot_stats(hal: Any) -> dict[str, Any]:
    for reply in hal.session.get(hal.keys.stats, timeout=2.0):
        if reply.ok is not None:
            return dict(json.loads(reply.ok.payload.to_bytes()))
    return {}


def _standing(hal: Any, objects: CameraObjects, truth: ZenohMocap, seconds: float) -> dict[str, Any]:
    """The HAL's control loop holding the robot while the camera senses; errors against the truth."""
    errors: list[float] = []
    per_object: dict[str, list[float]] = {}
    distances: dict[str, float] = {}
    hal.activate()
    st = hal.read_state()
    assert st is not None
    names = hal.setpoint_names
    hold = np.array([st.position(n) for n in names])
    frames0 = objects.frames
    received0 = objects.frames + objects.skipped + objects.rejects.total
    clock = ControlClock(hal, 0.01)  # the executive's control period, at its priority
    try:
        with realtime_priority() as grant:
            t_start = time.perf_counter()
            clock.restart()
            next_sample = t_start + 1.0  # the first second: views fused
            while time.perf_counter() - t_start < seconds:
                hal.read_state()
                hal.write_setpoint(hold, np.zeros(len(names)), names)
                now = time.perf_counter()
                if now >= next_sample:
                    next_sample = now + 0.2
                    sensed, true = objects.poses(), truth.poses()
                    st = hal.read_state()
                    T_cam = hal.model.fk(st.model_q(hal.model.joint_names), hal.model.config.frames["camera"])
                    for name, T in sensed.items():
                        if name in true:
                            e = float(np.linalg.norm(T[:3, 3] - true[name][:3, 3]) * 1e3)
                            errors.append(e)
                            per_object.setdefault(name, []).append(e)
                            distances[name] = float(np.linalg.norm(true[name][:3, 3] - T_cam[:3, 3]))
                clock.tick()
    finally:
        hal.deactivate()
    period_err_ms = clock.period_err_ms
    elapsed = time.perf_counter() - t_start
    return {
        "errors": errors,
        "per_object_mm_median": {n: float(np.median(v)) for n, v in per_object.items()},
        "distance_m": distances,
        "frames_per_s": (objects.frames + objects.skipped + objects.rejects.total - received0) / elapsed,
        "frames_processed_per_s": (objects.frames - frames0) / elapsed,
        "loop_period_err_ms_p99": _p(period_err_ms, 99),
        "loop_policy": grant.policy,
    }


def _first_motion(scene_path: Path, seed: int) -> dict[str, Any]:
    """Goal to first setpoint of a fresh executive on a fresh robot, sensing by camera included."""
    scene = load_scene(scene_path)
    with RobotProcess(scene_path, camera=True) as robot:
        hal, objects = connect(scene, RunOptions(backend="zenoh", endpoint=robot.endpoint, objects="camera"))
        assert isinstance(objects, CameraObjects)
        try:
            time.sleep(1.0)  # the camera streaming, as on a robot that has been on for a while
            ex = Executive(hal, scene, objects, seed=seed)
            t0 = time.perf_counter()
            first: list[float] = []

            def watch() -> None:  # cancel once the robot has been commanded: the figure is taken
                while not first and time.perf_counter() - t0 < 60.0 and ex.sm.state.name not in ("FAULT", "ESTOPPED"):
                    if ex.actor.cycles > 0:
                        first.append(time.perf_counter() - t0)
                        ex.cancel()
                        return
                    time.sleep(0.005)

            w = threading.Thread(target=watch, daemon=True)
            w.start()
            res = ex.run()  # SENSE (look_for included), PLAN, timing, the first setpoint
            w.join(timeout=1.0)
            found = ex.last_look
            assert isinstance(found, LookResult), "the executive did not look with the camera"
            ttfm = res.time_to_first_motion_s
            return {
                "look_for_s": found.elapsed_s,
                "seen": sorted(found.seen),
                "not_seen": sorted(found.missing),
                "undetectable": dict(found.undetectable),
                "head_views": found.views,
                "planning_time_s": res.planning_time_s,
                # the rest: the SENSE steps around look_for, the planner's set-up, timing, the actor's start
                "other_s": None if ttfm is None else ttfm - found.elapsed_s - res.planning_time_s,
                "time_to_first_motion_s": ttfm,
                "time_to_first_motion_watch_s": first[0] if first else None,
                "status": res.status.value,
            }
        finally:
            objects.close()
            hal.shutdown()


def run_camera_bench(scene_path: Path = SCENE, seconds: float = 10.0, seed: int = 0) -> dict[str, Any]:
    scene = load_scene(scene_path)
    with RobotProcess(scene_path, camera=True) as robot:
        hal, objects = connect(scene, RunOptions(backend="zenoh", endpoint=robot.endpoint, objects="camera"))
        assert isinstance(objects, CameraObjects)
        truth = ZenohMocap(hal.session)  # type: ignore[attr-defined]
        try:
            time.sleep(1.0)
            log.info("standing still: %.0f s of head-camera poses against the truth", seconds)
            stand = _standing(hal, objects, truth, seconds)
            robot_stats = _robot_stats(hal)
            stats = objects.stats()
            latency = list(objects.latency_ms)
        finally:
            truth.close()
            objects.close()
            hal.shutdown()
    log.info("time to first motion: a task with the camera in the loop")
    motion = _first_motion(scene_path, seed)
    errors = stand.pop("errors")
    return {
        "task": "camera",
        "scene": scene.name,
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version(), "load_avg_1m": os.getloadavg()[0]},
        "standing": {**stand, "source": stats, "robot_server": robot_stats},
        "first_motion": motion,
        "summary": {
            "pos_err_mm_median": _p(errors, 50),
            "pos_err_mm_p95": _p(errors, 95),
            "samples": len(errors),
            "latency_ms_median": _p(latency, 50),
            "latency_ms_p99": _p(latency, 99),
            "frames_per_s": stand["frames_per_s"],
            "frames_processed_per_s": stand["frames_processed_per_s"],
            "loop_period_err_ms_p99": stand["loop_period_err_ms_p99"],
            "robot_loop_period_err_ms_p99": robot_stats.get("loop_period_err_ms_p99", math.nan),
            "time_to_first_motion_s": motion["time_to_first_motion_s"],
        },
    }
