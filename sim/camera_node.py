"""The simulated robot's head camera on the wire: a process of its own that renders what the robot sees.

    python -m rlgp_exec.sim.camera_node --robot hsr --scene SCENE [--endpoint tcp/127.0.0.1:7447] [--rate 15] [--jpeg]

A Zenoh client of the simulated robot server (``rlgp_exec.sim.robot_server``; started with it by ``rlgp-exec sim-robot
--camera`` or ``RobotProcess(camera=True)``). It subscribes to the robot's joint states and odometry and to
the simulation's true object poses (the server's ``rlgp/mocap/objects``), loads the same scene for the
fixtures, and at ``--rate`` Hz puts the robot at its latest measured configuration, renders the head camera
(PyBullet TinyRenderer, the model of ``rlgp_exec.perception.camera``) and publishes what the real robot's camera
driver publishes: ``sensor_msgs/Image`` (rgb8) and ``sensor_msgs/CameraInfo`` (optionally
``CompressedImage``, JPEG) on the keys of ``robots/<robot>/zenoh_keys.toml``, stamped with the joint
state's stamp (the robot's clock). Rendering takes tens of milliseconds: in its own process (at a lower
priority) it does not delay the robot's 100 Hz loop. Like a lazy camera driver it renders only while
someone subscribes to the images; without fresh robot state it publishes nothing.
"""

from __future__ import annotations

import argparse
import logging
import math
import os
import signal
import sys
import threading
import time
from collections import deque
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np
import zenoh

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.camera_source import StampedHistory
from rlgp_exec.executive.world import DRAWER_SUFFIX, MOCAP_KEY, drawer_openings
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal import ros_image as ri
from rlgp_exec.hal.validate import RejectCounter, guarded
from rlgp_exec.hal.zenoh_keys import DEFAULT_ENDPOINT, load_key_map, session_config
from rlgp_exec.perception.camera import camera_for_robot
from rlgp_exec.perception.rendered_camera import hide_floor, render_camera
from rlgp_exec.scene import load_scene
from rlgp_exec.sim.logs import configure_logging
from rlgp_exec.world.pybullet_world import build_world

__all__ = ["CameraNode", "main"]

log = logging.getLogger("rlgp_exec.sim.camera_node")

STALE_S = 0.25  # [s] wall time: a joint state older than this is not the robot now: render nothing
ODOM_MATCH_S = 0.006  # [s] odometry this close to the joint state's stamp is the same robot tick
NOISE_FRAMES = 8  # pre-drawn pixel-noise frames, cycled (drawing 0.9 M normals costs more than a render)


def client_config(endpoint: str) -> Any:
    """A client session to ``endpoint``: the robot's peer routes a client's samples to its other peers."""
    c = session_config(connect=endpoint)
    c.insert_json5("mode", '"client"')
    return c


class CameraNode:
    def __init__(
        self,
        robot: str,
        scene_path: str,
        endpoint: str = DEFAULT_ENDPOINT,
        namespace: str = "",
        rate_hz: float = 15.0,
        jpeg: bool = False,
        noise_std: float = 1.0,
        seed: int = 0,
    ) -> None:
        self.scene = load_scene(scene_path)
        if self.scene.robot.name != robot:
            raise RlgpError(f"--scene {scene_path} is for robot {self.scene.robot.name!r}, not --robot {robot!r}")
        self.keys = load_key_map(robot, namespace)
        self.mocap_key = f"{namespace.strip('/')}/{MOCAP_KEY}" if namespace else MOCAP_KEY
        self.endpoint, self.period, self.jpeg = endpoint, 1.0 / rate_hz, jpeg
        self.world = build_world(self.scene)
        self.model = self.world.robot_model
        self.camera = camera_for_robot(robot)
        self.frame_id = self.model.config.frames["camera"]
        self.background = hide_floor(self.world)
        rng = np.random.default_rng(seed)
        shape = (self.camera.height, self.camera.width, 3)
        noise = [rng.normal(0.0, noise_std, shape).round() for _ in range(NOISE_FRAMES)]
        # as (+, -) parts: two saturating uint8 operations add it and clip, ~30x faster than int16 arithmetic
        self._noise = [(np.clip(n, 0, 255).astype(np.uint8), np.clip(-n, 0, 255).astype(np.uint8)) for n in noise]
        self._noise_on = noise_std > 0
        self.rejects = RejectCounter("camera_node")
        self._lock = threading.Lock()
        self.history = StampedHistory(self.model, self.rejects, history_s=1.0)
        self._truth: dict[str, np.ndarray] = {}
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._session: Any = None
        self._pubs: dict[str, Any] = {}
        self._subs: list[Any] = []
        self.frames = 0
        self._last_stamp = -math.inf  # the robot's clock at the last frame [s]
        self.render_ms: deque[float] = deque(maxlen=200)
        self.failures: dict[str, int] = {}  # why a frame failed -> how many did

    # ------------------------------------------------------------------ set-up
    def start(self, connect_timeout_s: float = 30.0) -> None:
        end = time.monotonic() + connect_timeout_s
        while True:  # the robot server may still be starting
            try:
                self._session = zenoh.open(client_config(self.endpoint))
                break
            except Exception as e:  # zenoh raises ZError when nothing listens yet
                if time.monotonic() > end:
                    raise RlgpError(f"camera node: cannot reach the robot at {self.endpoint}: {e}") from e
                time.sleep(0.2)
        rc.prepare()
        s, k = self._session, self.keys
        handlers = {
            k["joint_states"].key: self.history.on_joint_states,
            k["odom"].key: self.history.on_odom,
            self.mocap_key: self._on_truth,
        }
        self._subs = [s.declare_subscriber(key, guarded(self.rejects, key, fn, key)) for key, fn in handlers.items()]
        for name in ("camera_info", "camera_image") + (("camera_compressed",) if self.jpeg else ()):
            # below the robot's state and commands, dropped rather than queued when the link is busy: a
            # 0.9 MB frame ahead of a joint state held the state up for up to 1.5 s at the default priority
            self._pubs[name] = s.declare_publisher(
                k[name].key, priority=zenoh.Priority.DATA_LOW, congestion_control=zenoh.CongestionControl.DROP
            )
        self._thread = threading.Thread(target=self._run, name="camera-node", daemon=True)
        self._thread.start()
        log.info("camera node: %s at %.0f Hz on %s", k["camera_image"].key, 1.0 / self.period, self.endpoint)

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        if self._session is not None:
            self._session.close()
            self._session = None
        self.world.close()

    # ------------------------------------------------------------------ incoming
    def _on_truth(self, payload: bytes) -> None:
        try:
            poses = rc.parse_transforms(payload)
        except RlgpError as e:
            self.rejects.reject("truth", str(e))
            return
        with self._lock:
            self._truth = poses

    # ------------------------------------------------------------------ frames
    def _robot_now(self) -> tuple[float, np.ndarray] | None:
        """(stamp, q (nq,)) of the latest joint state and the odometry of its tick, if fresh."""
        latest = self.history.latest()
        if latest is None or time.monotonic() - latest[1] > STALE_S or latest[0] <= self._last_stamp:
            return None  # no fresh state, or no new one since the last frame (a frame per robot tick at most)
        at = self.history.at(latest[0], ODOM_MATCH_S)
        return None if at is None else (latest[0], at[0])

    def subscribed(self) -> bool:
        """Whether anyone subscribes to the images (a lazy driver renders only then)."""
        images = [p for n, p in self._pubs.items() if n != "camera_info"]
        return any(p.matching_status.matching for p in images)

    def render_frame(self) -> bool:
        """Render and publish one frame at the robot's latest state; False when there is none, or no one
        subscribes to the images (rendering takes a core: not for nobody)."""
        if not self.subscribed():
            return False
        now = self._robot_now()
        if now is None:
            return False
        stamp, q = now
        self._last_stamp = stamp
        t0 = time.perf_counter()
        with self._lock:
            truth = dict(self._truth)
        self.world.robot.set_q(q)
        for name in self.world.objects:
            if name in truth:
                self.world.set_object_pose(name, truth[name])
        for cabinet, opening in drawer_openings(self.scene, truth).items():
            if f"{cabinet}{DRAWER_SUFFIX}" in truth:
                self.world.set_drawer_opening(cabinet, opening)
        img = render_camera(self.world, self.camera, background=self.background)
        if self._noise_on:
            plus, minus = self._noise[self.frames % NOISE_FRAMES]
            img = cv2.subtract(cv2.add(img, plus), minus)
        c = self.camera
        self._pubs["camera_info"].put(ri.encode_camera_info(stamp, self.frame_id, c.width, c.height, c.K))
        self._pubs["camera_image"].put(ri.encode_image(stamp, self.frame_id, img))
        if self.jpeg:
            self._pubs["camera_compressed"].put(ri.encode_compressed(stamp, self.frame_id, img))
        self.frames += 1
        self.render_ms.append((time.perf_counter() - t0) * 1e3)
        return True

    def _run(self) -> None:
        nxt = time.perf_counter()
        last_report = time.monotonic()
        while not self._stop.is_set():
            try:
                self.render_frame()
            except Exception as e:  # a bad frame must not end the camera; each kind of failure told once
                why = f"{type(e).__name__}: {e}"
                self.failures[why] = self.failures.get(why, 0) + 1
                if self.failures[why] == 1:
                    log.exception("camera node: frame failed (%s); further ones counted", why)
            nxt += self.period
            now = time.perf_counter()
            if now > nxt:  # rendering took longer than a period: the next frame at once, no backlog
                nxt = now
            self._stop.wait(max(0.0, nxt - now))
            if time.monotonic() - last_report > 10.0:
                last_report = time.monotonic()
                ms = float(np.median(self.render_ms)) if self.render_ms else float("nan")
                log.info("camera node: %d frames, frame median %.1f ms", self.frames, ms)
                if self.failures:
                    log.warning("camera node: frames failed: %s", self.failures)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m rlgp_exec.sim.camera_node", description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", choices=["hsr", "pr2"], required=True)
    ap.add_argument("--scene", required=True, help="the scene the robot server simulates (its fixtures and objects)")
    ap.add_argument("--endpoint", default=DEFAULT_ENDPOINT, help="the robot server's endpoint")
    ap.add_argument("--namespace", default="", help="key prefix (the bridge's namespace)")
    ap.add_argument("--rate", type=float, default=15.0, help="frames per second")
    ap.add_argument("--jpeg", action="store_true", help="also publish sensor_msgs/CompressedImage (JPEG)")
    ap.add_argument("--noise", type=float, default=1.0, help="pixel noise std [grey levels]")
    ap.add_argument("-v", "--verbose", action="count", default=0)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Run until SIGINT/SIGTERM. Exit 0 on a clean stop, 2 on bad input."""
    args = _parser().parse_args(None if argv is None else list(argv))
    configure_logging(args.verbose)
    os.nice(10)  # the robot's 100 Hz loop comes first when the cores are busy: rendering can wait
    if not 0 < args.rate <= 60:
        print(f"rlgp_exec.sim.camera_node: --rate must be in (0, 60] Hz, got {args.rate}", file=sys.stderr)
        return 2
    try:
        node = CameraNode(args.robot, args.scene, args.endpoint, args.namespace, args.rate, args.jpeg, args.noise)
        node.start()
    except RlgpError as e:
        print(f"rlgp_exec.sim.camera_node: error: {e}", file=sys.stderr)
        return 2
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    print(f"camera_node ready: {args.robot} {node.keys['camera_image'].key}", flush=True)
    try:
        done.wait()
    finally:
        node.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
