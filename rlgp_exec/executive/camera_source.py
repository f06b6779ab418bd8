"""``CameraObjects``: object poses from the robot's own head camera over the HAL's Zenoh session.

Subscribes to the camera's ``sensor_msgs/Image`` and ``CameraInfo`` (keys ``camera_image`` and
``camera_info`` of ``robots/<robot>/zenoh_keys.toml``; a robot that publishes only
``sensor_msgs/CompressedImage``, JPEG or PNG, key ``camera_compressed``, is read from those: the first
kind of image that arrives is the one used) and, for a stamped history, to the joint states
and odometry. Each image is processed in a worker thread (the newest waiting one; frames that arrive
while one is processed replace each other and are counted as skipped): AprilTag detection and PnP
(``perception``), then the tag is put in the world through the camera pose from forward kinematics at
the joint state *nearest the image's stamp* (the robot moved since), fused over views by the tracker.

An estimate is returned by :meth:`poses` while it is fresh: younger than ``max_age_s`` on the robot's
clock. One that should be in view, close and facing the camera, but is not detected in ``MISSES``
frames in a row is forgotten (the object is not there any more). The hand is followed by
proprioception, as the head camera seldom sees into it: when the gripper closes with the tool frame at
an object's estimate, the object rides with the tool (its pose follows the tool frame at the latest joint
state); when the gripper opens again, it stays where the tool left it. Drawers, which the camera sees
neither the travel of nor into, are kept the same way (:mod:`rlgp_exec.executive.drawer_memory`): their
frames ``<cabinet>.drawer`` are among the poses. Without fresh joint states
or images nothing is returned. Bad payloads and images are dropped and counted (:attr:`rejects`), with
a warning for the first few of each kind; they never give a pose.

:meth:`look_for` is what SENSE calls: it points the head, through the HAL, at where each wanted object
may be until every one is seen, and says which were not.
"""

from __future__ import annotations

import bisect
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, replace
from typing import Any, NamedTuple

import cv2
import numpy as np

from rlgp_exec.executive.drawer_memory import DrawerMemory
from rlgp_exec.executive.head_view import HeadView, HeadViews
from rlgp_exec.executive.world import ObjectSource
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal import ros_image as ri
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import Lifecycle
from rlgp_exec.hal.validate import RejectCounter, guarded
from rlgp_exec.hal.zenoh_keys import KeyMap
from rlgp_exec.perception.camera import CameraIntrinsics, PerceptionError, camera_for_robot
from rlgp_exec.perception.detector import TagDetector
from rlgp_exec.perception.look_around import candidate_points
from rlgp_exec.perception.pipeline import Perception
from rlgp_exec.perception.pose import MIN_CORNER_SIGMA_PX
from rlgp_exec.perception.registry import TagRegistry
from rlgp_exec.perception.resting import RestingSupports
from rlgp_exec.perception.tracker import ObjectEstimate, ObjectTracker
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene

__all__ = ["CameraObjects", "LookResult", "StampedHistory"]

log = logging.getLogger(__name__)

MATCH_S = 0.02  # [s] an image needs a joint state (and odometry) this close to its stamp
HISTORY_S = 3.0  # [s] of joint states and odometry kept
STATE_STALE_S = 0.5  # [s] wall: joint states older than this -> the robot is not being heard: no poses
IMAGE_STALE_S = 1.0  # [s] wall: no image processed for this long -> the camera is not working: no poses
TOUCH_M = 0.10  # [m] the tool frame this close to an object's estimate when the gripper closes: grasped
CLOSED_FRACTION = 0.25  # the gripper this far from open towards closed: closing (on an object)
OPEN_FRACTION = 0.1  # ... and back within this much of open: released
RELEASED_STD_M = 0.005  # [m] the error figure of an object put down, not seen, where the tool left it
MISSES = 3  # frames in a row an object in plain view is not detected before its estimate is forgotten
OCCLUDED_M = 0.3  # [m] an object this close to the tool frame may be hidden by the hand: not a miss
VIEW_RANGE_M = (0.3, 1.2)  # [m] distances at which a tag facing the camera is surely detected
FACING_COS = 0.7  # the tag's normal within 45 deg of the line of sight
# [m] a tag pose's error figure (pose.estimate_tag_pose) over this places nothing: from a small, far tag the
# depth error sinks a resting object into its table or lifts it off (~12 px for a 4 cm tag)
PLACE_STD_MAX_M = 0.045
MIN_OBSERVATIONS = 2  # look_for: images an object must be seen in
CONFIRM = 2  # images in a row that must agree before an object counts as moved (the tracker's confirm)
# a jump beyond max(GATE_SIGMA sigma, GATE_MIN_M) is a move: the PnP error figures are ~5x the errors seen
# at 0.6-1.2 m, so the tracker's default 6 sigma took a 6 cm push for noise and blended it in over seconds
GATE_SIGMA = 2.5
GATE_MIN_M = 0.02
MIN_SIDE_MARGIN = 1.3  # look_for: a view of another place whose tag would be under this x the detector's minimum
# is skipped (a view of where the object is believed to be is taken down to the minimum itself)
HEARTBEAT_WAIT_S = 1.0  # [s] look_for waits this long for fresh robot state before it gives up


class StampedHistory:
    """Joint states and base poses by the robot's clock, the last ``history_s`` seconds, for the
    configuration at an image's stamp. Thread-safe."""

    def __init__(self, model: RobotModel, rejects: RejectCounter, history_s: float = HISTORY_S) -> None:
        self.model, self.rejects, self.history_s = model, rejects, history_s
        self._lock = threading.Lock()
        self._js_t: list[float] = []
        self._js: list[tuple[tuple[str, ...], np.ndarray, float]] = []  # names, q, wall arrival
        self._base_t: list[float] = []
        self._base: list[tuple[float, float, float]] = []

    @staticmethod
    def _insert(ts: list[float], vs: list[Any], t: float, v: Any, keep_s: float) -> None:
        i = bisect.bisect_right(ts, t)
        ts.insert(i, t)
        vs.insert(i, v)
        if ts[-1] - ts[0] > 2 * keep_s:  # trim in batches: a list's front deletion is O(n)
            k = bisect.bisect_left(ts, ts[-1] - keep_s)
            del ts[:k], vs[:k]

    def on_joint_states(self, payload: bytes) -> None:
        """A sensor_msgs/JointState payload in (bad ones counted)."""
        r = rc.parse_joint_state(payload)
        if isinstance(r, rc.Rejected):
            self.rejects.reject(r.key, f"joint_states: {r.reason}")
            return
        unknown = [n for n in r[1] if n not in self.model.joint_names]
        if unknown:
            self.rejects.reject("unknown_joint", f"joint_states: unknown joint(s) {unknown}")
            return
        self.add_joints(r[0], r[1], r[2], time.monotonic())

    def on_odom(self, payload: bytes) -> None:
        """A nav_msgs/Odometry payload in (bad ones counted)."""
        r = rc.parse_odometry(payload)
        if isinstance(r, rc.Rejected):
            self.rejects.reject(r.key, f"odom: {r.reason}")
            return
        self.add_base(r[0], r[1])

    def add_joints(self, stamp: float, names: tuple[str, ...], q: np.ndarray, wall: float) -> None:
        with self._lock:
            self._insert(self._js_t, self._js, stamp, (names, q, wall), self.history_s)

    def add_base(self, stamp: float, base: tuple[float, float, float]) -> None:
        with self._lock:
            self._insert(self._base_t, self._base, stamp, base, self.history_s)

    @staticmethod
    def _nearest(ts: list[float], t: float) -> int | None:
        if not ts:
            return None
        i = bisect.bisect_left(ts, t)
        cands = [j for j in (i - 1, i) if 0 <= j < len(ts)]
        return min(cands, key=lambda j: abs(ts[j] - t))

    def at(self, stamp: float, tol: float = MATCH_S) -> tuple[FloatArray, float] | None:
        """(q (nq,), the wall time the joint state arrived) nearest ``stamp`` [s], or None when no joint
        state or base pose lies within ``tol`` of it."""
        with self._lock:
            i, j = self._nearest(self._js_t, stamp), self._nearest(self._base_t, stamp)
            if i is None or j is None or abs(self._js_t[i] - stamp) > tol or abs(self._base_t[j] - stamp) > tol:
                return None
            names, qj, wall = self._js[i]
            base = self._base[j]
        q = self.model.home(base)
        for n, v in zip(names, qj, strict=True):
            q[self.model.index(n)] = v
        return q, wall

    def earliest(self) -> float | None:
        """The stamp [s] of the oldest joint state kept."""
        with self._lock:
            return self._js_t[0] if self._js_t else None

    def latest(self) -> tuple[float, float] | None:
        """(stamp [s], wall arrival [s]) of the newest joint state."""
        with self._lock:
            return (self._js_t[-1], self._js[-1][2]) if self._js_t else None


@dataclass(frozen=True)
class LookResult:
    seen: frozenset[str]
    missing: frozenset[str]  # wanted and not seen (untagged objects among them)
    untagged: frozenset[str]  # wanted, but carrying no tag: a camera cannot see them
    views: int  # head poses commanded
    elapsed_s: float
    detail: str
    #: (object, why) wanted objects no view from where the robot stands shows large enough: not searched for
    undetectable: tuple[tuple[str, str], ...] = ()

    @property
    def ok(self) -> bool:
        return not self.missing

    @property
    def unverified(self) -> frozenset[str]:
        """Tagged objects wanted and not seen: planned on their prior pose until the camera sees them."""
        return self.missing - self.untagged


class _Compressed(NamedTuple):
    """A CompressedImage payload waiting for the worker (a bare ``bytes`` one is a raw Image)."""

    payload: bytes


class CameraObjects(ObjectSource):
    """Object poses from the head camera's images on ``session`` (the HAL's)."""

    def __init__(
        self,
        session: Any,
        keys: KeyMap,
        model: RobotModel,
        scene: Scene,
        *,
        max_age_s: float = 60.0,
        detector: str = "opencv",
        worker: bool = True,
        images: bool = True,
    ) -> None:
        """``images``: subscribe to the robot's camera topics; False when frames come from elsewhere
        (:meth:`submit`, a local camera: :mod:`rlgp_exec.executive.local_camera`)."""
        # one OpenCV thread: with the robot and its renderer on the same cores, a parallel detection waits
        # for its slowest thread to be scheduled again
        cv2.setNumThreads(1)
        self.model, self.scene, self.max_age_s = model, scene, max_age_s
        self.camera_frame = model.config.frames["camera"]
        self.tool_frame = model.manipulator().tool_frame
        self.registry = TagRegistry.from_scene(scene)
        tracker = ObjectTracker(max_age_s=max_age_s, gate_sigma=GATE_SIGMA, gate_min_m=GATE_MIN_M, confirm=CONFIRM)
        self.perception = Perception(
            self.registry, camera_for_robot(model.name), TagDetector(detector), tracker, max_pos_std_m=PLACE_STD_MAX_M,
            supports=RestingSupports(scene),
        )
        self.head_views = HeadViews(model, scene, self.perception.camera)  # look_for's thread only (PyBullet)
        self.rejects = RejectCounter("camera")
        self.history = StampedHistory(model, self.rejects)
        self.frames = 0  # images processed
        self.skipped = 0  # images replaced by a newer one before they were processed
        self.before_history = 0  # images stamped before the first joint state this source received
        self.latency_ms: deque[float] = deque(maxlen=2000)  # image stamp (its joint state's arrival) to pose
        self.process_ms: deque[float] = deque(maxlen=2000)
        self._info: ri.CameraModel | None = None
        self._info_cam: tuple[ri.CameraModel, CameraIntrinsics] | None = None
        self._lock = threading.Lock()  # the tracker and the bookkeeping below
        self._held: tuple[str, FloatArray] | None = None  # (object, T_tool_object (4, 4)) while grasped
        self.drawers = DrawerMemory(scene)  # drawer openings and contents, by the hand (the lock held)
        grip = model.manipulator()
        self._gripper_i = model.index(model.joint_names[model.group(grip.gripper)[0]])
        self._grip_open, self._grip_closed = float(grip.open), float(grip.closed)
        self._misses: dict[str, int] = {}
        self._last_stamp = -math.inf
        self._last_wall = -math.inf
        self._image_kind: str | None = None  # "raw" or "compressed": the first image's kind, the one used
        self.other_kind = 0  # images of the other kind, left (a robot publishing both is read once)
        self._pending: bytes | _Compressed | ri.ImageFrame | None = None  # the newest image not yet processed
        self._wake = threading.Condition()
        self._stop = False
        self._subs: list[Any] = []
        self.feeds: list[Any] = []  # what submits frames (a local camera), closed with this source
        self._thread: threading.Thread | None = None
        if worker:  # before the subscriptions: on_image hands frames to it from the first one
            self._thread = threading.Thread(target=self._work, name="camera-objects", daemon=True)
            self._thread.start()
        if session is not None:
            handlers = {"joint_states": self.history.on_joint_states, "odom": self.history.on_odom}
            if images:
                handlers |= {"camera_image": self.on_image, "camera_compressed": self.on_compressed,
                             "camera_info": self.on_camera_info}
            self._subs = [
                session.declare_subscriber(keys[t].key, guarded(self.rejects, t, fn, keys[t].key))
                for t, fn in handlers.items()
            ]

    # ------------------------------------------------------------------ incoming (Zenoh threads)
    def on_camera_info(self, payload: bytes) -> None:
        m = ri.parse_camera_info(payload)
        if isinstance(m, rc.Rejected):
            self.rejects.reject(m.key, m.reason)
            return
        self._info = m

    def on_image(self, payload: bytes) -> None:
        """Hand an Image payload to the worker (the newest waiting one wins), or without a worker decode
        and process it here. The Zenoh thread only stores it: the robot's state arrives on that thread too."""
        if self._first_kind("raw"):
            self._offer(payload)

    def on_compressed(self, payload: bytes) -> None:
        """A CompressedImage payload (JPEG or PNG; a robot that publishes only ``.../compressed``), as ``on_image``."""
        if self._first_kind("compressed"):
            self._offer(_Compressed(payload))

    def _first_kind(self, kind: str) -> bool:
        """Whether images of ``kind`` are the ones used: those of the first image that arrived."""
        with self._wake:
            if self._image_kind is None:
                self._image_kind = kind
            if kind != self._image_kind:
                self.other_kind += 1
                return False
            return True

    def _offer(self, payload: bytes | _Compressed) -> None:
        if self._thread is None:
            self._handle(payload)
            return
        with self._wake:
            if self._pending is not None:
                self.skipped += 1
            self._pending = payload
            self._wake.notify()

    def set_camera_model(self, model: ri.CameraModel) -> None:
        """The camera model of the images :meth:`submit` hands in (what a CameraInfo gives otherwise)."""
        self._info = model

    def submit(self, frame: ri.ImageFrame) -> None:
        """Hand a decoded image, stamped in the robot's clock, to the worker (the newest waiting one wins)."""
        if self._thread is None:
            self.process(frame)
            return
        with self._wake:
            if self._pending is not None:
                self.skipped += 1
            self._pending = frame
            self._wake.notify()

    def _handle(self, payload: bytes | _Compressed | ri.ImageFrame) -> None:
        if isinstance(payload, ri.ImageFrame):
            self.process(payload)
            return
        f = ri.parse_compressed(payload.payload) if isinstance(payload, _Compressed) else ri.parse_image(payload)
        if isinstance(f, rc.Rejected):
            self.rejects.reject(f.key, f.reason)
            return
        self.process(f)

    # ------------------------------------------------------------------ processing (worker thread)
    def _work(self) -> None:
        while True:
            with self._wake:
                while self._pending is None and not self._stop:
                    self._wake.wait()
                if self._stop:
                    return
                job, self._pending = self._pending, None
            if job is None:
                continue
            try:
                self._handle(job)
            except Exception:  # a bug on one frame must not end sensing
                log.exception("camera: processing a frame failed")

    def _intrinsics(self, frame: ri.ImageFrame) -> CameraIntrinsics | None:
        info = self._info
        if info is None:
            self.rejects.reject("no_camera_info", "image before any valid CameraInfo: no camera model")
            return None
        if frame.size != (info.width, info.height):
            self.rejects.reject(
                "size_mismatch", f"image {frame.size[0]}x{frame.size[1]} but CameraInfo {info.width}x{info.height}"
            )
            return None
        if self._info_cam is None or self._info_cam[0] is not info:  # a new CameraInfo: a new model
            K = info.K
            self._info_cam = (info, CameraIntrinsics(info.width, info.height, K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
        return self._info_cam[1]

    def process(self, frame: ri.ImageFrame) -> bool:
        """Detect, place and fuse one image; False (counted) when it is not usable."""
        t0 = time.perf_counter()
        if frame.frame_id and frame.frame_id != self.camera_frame:
            self.rejects.reject("frame_id", f"image in frame {frame.frame_id!r}, the camera is {self.camera_frame!r}")
            return False
        if not math.isfinite(frame.stamp) or frame.stamp <= self._last_stamp:
            self.rejects.reject("out_of_order", f"image stamp {frame.stamp} not after the last one {self._last_stamp}")
            return False
        cam = self._intrinsics(frame)
        if cam is None:
            return False
        at = self.history.at(frame.stamp)
        first = self.history.earliest()
        if at is None and self._last_stamp == -math.inf and (first is None or frame.stamp < first):
            self.before_history += 1  # taken before this source heard the robot (start-up): not an error
            return False
        if at is None:
            self.rejects.reject(
                "no_joint_state", f"no joint state within {MATCH_S * 1e3:.0f} ms of image stamp {frame.stamp:.3f}"
            )
            return False
        q, wall_js = at
        T_world_camera, T_world_tool = self.model.fk_many(q, [self.camera_frame, self.tool_frame])
        try:  # outside the lock: the control loop reads poses while a frame's tags are found
            found = self.perception.detector.detect(frame.image)
        except PerceptionError as e:
            self.rejects.reject("bad_image", str(e))
            return False
        with self._lock:
            self.perception.camera = cam
            try:
                lifted = frozenset() if self._held is None else frozenset({self._held[0]})
                rep = self.perception.locate(found, T_world_camera, frame.stamp, lifted)
            except PerceptionError as e:
                self.rejects.reject("bad_image", str(e))
                return False
            self._follow_hand(T_world_tool, float(q[self._gripper_i]), frame.stamp)
            self._bookkeep(set(rep.updated), T_world_camera, T_world_tool[:3, 3], cam)
            self._last_stamp = frame.stamp
            self._last_wall = time.monotonic()
        self.frames += 1
        self.latency_ms.append((time.monotonic() - wall_js) * 1e3)
        self.process_ms.append((time.perf_counter() - t0) * 1e3)
        return True

    def _follow_hand(self, T_world_tool: FloatArray, gripper: float, stamp: float) -> None:
        """Grasp and release (objects and drawer knobs) from the gripper joint and the tool frame (the
        lock held)."""
        span = self._grip_open - self._grip_closed
        tracker = self.perception.tracker
        p_tool = T_world_tool[:3, 3]
        empty = self._held is None and self.drawers.knob is None
        if empty and gripper < self._grip_open - CLOSED_FRACTION * span:
            # where each object is believed to be: its estimate, else the scene's prior (never seen yet)
            believed = {o.name: o.T for o in self.scene.objects if o.tag is not None}
            believed.update({n: e.T_world_object for n, e in tracker.estimates().items()})
            near = [(float(np.linalg.norm(T[:3, 3] - p_tool)), n) for n, T in believed.items()]
            near = [x for x in near if x[0] < TOUCH_M]
            knob = self.drawers.nearest_knob(p_tool)
            if knob is not None and (not near or knob[0] <= min(near)[0]):
                self.drawers.take_knob(knob[1], p_tool, believed)
            elif near:
                d, name = min(near)
                self._held = (name, np.linalg.inv(T_world_tool) @ believed[name])
                log.info("camera: %s grasped (gripper at %.2f, tool %.3f m from it)", name, gripper, d)
        elif self._held is not None and gripper > self._grip_open - OPEN_FRACTION * span:
            name, T_tool_object = self._held
            self._held = None
            T = self.drawers.settle(name, T_world_tool @ T_tool_object)
            self._put(name, T, stamp)
            log.info("camera: %s released", name)
        elif self.drawers.knob is not None and gripper > self._grip_open - OPEN_FRACTION * span:
            shift = self.drawers.shift(self.drawers.opening_now(p_tool) or 0.0)
            for name in self.drawers.release_knob(p_tool):
                est = tracker.estimate(name)
                prior = next((o.T for o in self.scene.objects if o.name == name), None)
                T_now = prior if est is None else est.T_world_object
                if T_now is not None and shift is not None:
                    T_moved = T_now.copy()
                    T_moved[:3, 3] += shift
                    self._put(name, T_moved, stamp)

    def _put(self, name: str, T_world_object: FloatArray, stamp: float) -> None:
        """Set an object's estimate from the hand (no image saw it there); as sure as a fused one."""
        tracker = self.perception.tracker
        est = tracker.estimate(name)
        if est is None:  # grasped where the scene had it, never seen
            est = ObjectEstimate(name, T_world_object, RELEASED_STD_M, 10 * RELEASED_STD_M, stamp, MIN_OBSERVATIONS, ())
        n = max(est.n_updates, MIN_OBSERVATIONS)
        tracker.put(replace(est, T_world_object=T_world_object, stamp=stamp, n_updates=n))

    def _bookkeep(
        self, updated: set[str], T_world_camera: FloatArray, p_tool: FloatArray, cam: CameraIntrinsics
    ) -> None:
        """The objects missing from where they should be seen (the lock held); not those near the hand,
        which may hide them (just put down, the hand is above the tag)."""
        T_camera_world = np.asarray(np.linalg.inv(T_world_camera), dtype=np.float64)
        tracker = self.perception.tracker
        held = self._held[0] if self._held is not None else None
        for name, est in tracker.estimates().items():
            p = est.T_world_object[:3, 3]
            if name == held or float(np.linalg.norm(p - p_tool)) < OCCLUDED_M or self.drawers.hidden(p):
                self._misses.pop(name, None)
                continue
            if name in updated:
                self._misses[name] = 0
                continue
            if self._in_plain_view(name, est.T_world_object, T_camera_world, cam):
                self._misses[name] = self._misses.get(name, 0) + 1
                if self._misses[name] >= MISSES:
                    log.info("camera: %s not seen where it was in %d frames: estimate dropped", name, MISSES)
                    tracker.forget(name)
                    self._misses.pop(name, None)

    def _in_plain_view(
        self, name: str, T_world_object: FloatArray, T_camera_world: FloatArray, cam: CameraIntrinsics
    ) -> bool:
        """Whether a tag of ``name`` would be in the middle of the image, near, facing the camera."""
        mounts = [m for m in (self.registry.get(i) for i in self.registry.ids) if m is not None and m.object == name]
        for m in mounts:
            T_ct = T_camera_world @ T_world_object @ m.T_object_tag
            p, n = T_ct[:3, 3], T_ct[:3, 2]
            dist = float(np.linalg.norm(p))
            if not (VIEW_RANGE_M[0] <= dist <= VIEW_RANGE_M[1]) or p[2] <= 0:
                continue
            if float(-n @ p) / dist < FACING_COS:
                continue
            u, v = cam.project(p)[0]
            if 0.2 * cam.width <= u <= 0.8 * cam.width and 0.2 * cam.height <= v <= 0.8 * cam.height:
                return True
        return False

    # ------------------------------------------------------------------ the ObjectSource
    def _fresh(self, names: Iterable[str] | None = None, min_updates: int = 1) -> dict[str, FloatArray]:
        latest = self.history.latest()
        wall = time.monotonic()
        if latest is None or wall - latest[1] > STATE_STALE_S or wall - self._last_wall > IMAGE_STALE_S:
            return {}
        now = latest[0]
        out = {}
        with self._lock:
            ests = self.perception.tracker.estimates()
            held = self._held
        for name, est in ests.items():
            if names is not None and name not in names:
                continue
            if est.n_updates < min_updates:
                continue
            # what is in a drawer or a cabinet stays there unseen: it does not age out
            if now - est.stamp <= self.max_age_s or self.drawers.hidden(est.T_world_object[:3, 3]):
                out[name] = est.T_world_object
        at = self.history.at(now)
        T_tool = None if at is None else self.model.fk(at[0], self.tool_frame)  # the tool now, not at the last image
        if held is not None and (names is None or held[0] in names) and T_tool is not None:
            out[held[0]] = T_tool @ held[1]
        with self._lock:
            knob = self.drawers.knob
            if knob is not None and T_tool is not None:  # a drawer's contents ride with it
                shift = self.drawers.shift(self.drawers.opening_now(T_tool[:3, 3]) or 0.0)
                for name in knob.contents:
                    if name in out and shift is not None:
                        out[name] = out[name].copy()
                        out[name][:3, 3] += shift
            if names is None:
                out.update(self.drawers.frames(None if T_tool is None else T_tool[:3, 3]))
        return out

    def poses(self) -> dict[str, FloatArray]:
        """T_world_object of every object with a fresh estimate fused from MIN_OBSERVATIONS images or more
        (one view's estimate, a restart from a far or grazing view, is not evidence that an object moved);
        cheap: no image work happens here."""
        return self._fresh(None, MIN_OBSERVATIONS)

    def look_for(
        self,
        names: Sequence[str],
        hal: RobotInterface,
        *,
        timeout_s: float = 20.0,
        views_per_object: int = 3,
        settle_s: float = 0.25,
    ) -> LookResult:
        """Point the head (through ``hal``) where each object of ``names`` may be until each is seen in
        MIN_OBSERVATIONS images, or ``timeout_s`` passes. Objects already seen cost nothing. The HAL is
        activated for the head moves if it was inactive, and left as it was found. Stops (and says so) on
        a lost heartbeat or a refused command: never moves on stale state."""
        t0 = time.monotonic()
        tagged = set(self.registry.objects)
        wanted = set(names) & tagged
        untagged = frozenset(set(names) - tagged)
        views = 0
        detail = ""
        too_far: set[str] = set()

        def seen() -> set[str]:
            return set(self._fresh(wanted, MIN_OBSERVATIONS))

        q_found = self._measured_q(hal)
        # an object whose tag no view from here shows large enough is reported now, not searched for
        undetectable = {} if q_found is None else self._undetectable(sorted(wanted - seen()), q_found)
        searched = wanted - set(undetectable)
        # the images streaming now first (not waiting for what no image from here can show)
        self._wait_frames(2, t0 + min(timeout_s, 2.0), lambda: searched <= seen())
        activated = False
        try:
            for name in sorted(searched - seen()):
                for i, point in enumerate(candidate_points(self.scene, name)[:views_per_object]):
                    if detail or name in seen() or time.monotonic() - t0 > timeout_s:
                        break
                    if hal.lifecycle is Lifecycle.INACTIVE:
                        hal.activate()
                        activated = True
                    # where it is believed to be: worth a view down to the detector's limit; elsewhere with margin
                    margin = 1.0 if i == 0 else MIN_SIDE_MARGIN
                    why = self._point_head(hal, point, name, margin)
                    if why is None:  # the head cannot point there, or the tag would be too small to see
                        too_far.add(name)
                        continue
                    detail = why  # '' when the head got there
                    if not why:
                        views += 1
                        self._wait_frames(2, time.monotonic() + settle_s + 1.0, lambda n=name: n in seen(), settle_s)
            if views and not detail and q_found is not None:  # the head back where it was: a known posture
                q_now = self._measured_q(hal)
                if q_now is not None:
                    back = self._move_head(hal, q_now, q_found)
                    detail = "" if back == "stale" else back
        finally:
            if activated and hal.lifecycle is Lifecycle.ACTIVE:
                hal.deactivate()
        got = seen()
        missing = frozenset((wanted - got) | untagged)
        if not detail:
            detail = f"not seen: {sorted(missing)}" if missing else "all seen"
            far = sorted(too_far & missing)
            if far:
                detail += f" ({far}: no view from this base shows its tag large enough)"
            whys = [why for n, why in sorted(undetectable.items()) if n in missing]
            if whys:
                detail += f" ({'; '.join(whys)})"
        if missing:
            log.warning("look_for: %s (%d head views)", detail, views)
        return LookResult(
            frozenset(got), missing, untagged, views, time.monotonic() - t0, detail,
            tuple((n, why) for n, why in sorted(undetectable.items()) if n in missing),
        )

    def _undetectable(self, names: Sequence[str], q: FloatArray) -> dict[str, str]:
        """Why each of ``names`` cannot be detected from the base pose of ``q``: its tag at its believed
        pose (the estimate, else the scene's) under the detector's minimum from the best head view, or no
        free view of it."""
        with self._lock:
            ests = self.perception.tracker.estimates()
        out = {}
        for name in names:
            est = ests.get(name)
            point = candidate_points(self.scene, name, None if est is None else est.T_world_object[:3, 3])[0]
            view = self.head_views.view(q, point)
            if isinstance(view, str):
                out[name] = f"{name}: {view}"
                continue
            side, need = self._tag_side_px(name, view.q, point), self._need_side_px(name)
            if side < need:
                out[name] = f"{name}: ~{side:.0f} px tag side from here, placing it needs >= {need:.0f} px"
        return out

    def _wait_frames(self, n: int, deadline: float, done: Any, settle_s: float = 0.0) -> None:
        """Wait until ``n`` images taken after ``settle_s`` from now are processed, ``done()`` holds, or
        ``deadline`` passes."""
        time.sleep(settle_s)
        latest = self.history.latest()
        after = latest[0] if latest is not None else -math.inf
        count0 = None
        while time.monotonic() < deadline:
            if done():
                return
            if self._last_stamp >= after:
                count0 = self.frames if count0 is None else count0
                if self.frames - count0 >= n:
                    return
            time.sleep(0.02)

    def _tag_side_px(self, name: str, q: FloatArray, point: FloatArray) -> float:
        """The expected shortest side [px] of the largest tag of ``name`` at ``point`` (facing up, as on a
        standing object) in the image taken at ``q``."""
        sizes = [m.size for m in (self.registry.get(i) for i in self.registry.ids) if m and m.object == name]
        return self.head_views.tag_side_px(q, point, max(sizes, default=0.0))

    def _need_side_px(self, name: str) -> float:
        """The smallest tag side [px] that detects ``name`` and places it: the detector's minimum, or the side
        at which the error figure reaches PLACE_STD_MAX_M (sigma z / side, with z = size f / side)."""
        sizes = [m.size for m in (self.registry.get(i) for i in self.registry.ids) if m and m.object == name]
        cam = self.perception.camera
        placed = math.sqrt(MIN_CORNER_SIGMA_PX * max(sizes, default=0.0) * (cam.fx + cam.fy) / 2 / PLACE_STD_MAX_M)
        return max(float(self.perception.detector.min_side_px), placed)

    def _point_head(
        self, hal: RobotInterface, point: FloatArray, name: str, margin: float = MIN_SIDE_MARGIN, tries: int = 3
    ) -> str | None:
        """Move the head to look at ``point``: '' when done, None when the head cannot point there, else
        why it stopped. A heartbeat lost for a moment (a loaded machine) pauses the move; it starts again
        from the measured state once the state is fresh, up to ``tries`` times."""
        for _ in range(tries):
            why = self._head_move(hal, point, name, margin)
            if why != "stale":
                return why
            end = time.monotonic() + HEARTBEAT_WAIT_S
            while not hal.heartbeat_ok() and time.monotonic() < end:
                time.sleep(0.01)
        return f"look_for: no fresh robot state within {HEARTBEAT_WAIT_S} s: not moving the head"

    def _measured_q(self, hal: RobotInterface) -> FloatArray | None:
        """The robot's configuration as measured now, None without fresh state."""
        st = hal.read_state()
        if st is None or not hal.heartbeat_ok():
            return None
        q = self.model.home(st.base)
        for n in st.names:
            q[self.model.index(n)] = st.position(n)
        return q

    def _head_move(self, hal: RobotInterface, point: FloatArray, name: str, margin: float) -> str | None:
        q = self._measured_q(hal)
        if q is None:
            return "stale"
        view = self.head_views.view(q, point)  # never a posture (or a way there) that collides
        if not isinstance(view, HeadView):
            log.debug("look_for: no view of %s at %s: %s", name, np.round(point, 3), view)
            return None
        if self._tag_side_px(name, view.q, point) < margin * self._need_side_px(name):
            return None
        return self._move_head(hal, q, view.q)

    def _move_head(self, hal: RobotInterface, q: FloatArray, q_target: FloatArray) -> str:
        """Move the head joints from ``q`` to ``q_target`` (full configurations) on a cosine profile: '' when
        there, else why it stopped ("stale": the heartbeat was lost)."""
        idx = list(self.model.group("head"))
        names = tuple(self.model.joint_names[i] for i in idx)
        q0, q1 = q[idx], q_target[idx]
        vmax = 0.6 * self.model.limits.velocity[idx]
        T = max(0.2, float(np.max(np.abs(q1 - q0) * math.pi / (2 * vmax))))  # a cosine profile's peak speed
        period = 0.01
        t_start = time.monotonic()
        while True:
            t = min(time.monotonic() - t_start, T)
            s = 0.5 * (1 - math.cos(math.pi * t / T))
            ds = 0.5 * math.pi / T * math.sin(math.pi * t / T)
            if not hal.heartbeat_ok():
                return "stale"
            res = hal.write_setpoint(q0 + s * (q1 - q0), ds * (q1 - q0), names)
            if not res:
                return f"look_for: head command refused: {res.reason}"
            if t >= T:
                return ""
            time.sleep(period)

    def stats(self) -> dict[str, Any]:
        return {
            "frames": self.frames,
            "skipped": self.skipped,
            "too_far": self.perception.too_far,  # tag poses too uncertain to place an object (PLACE_STD_MAX_M)
            "onto_support": 0 if self.perception.supports is None else self.perception.supports.corrected,
            "rejected": self.rejects.counts(),
            "latency_ms_p99": float(np.percentile(self.latency_ms, 99)) if self.latency_ms else None,
            "process_ms_median": float(np.median(self.process_ms)) if self.process_ms else None,
        } | ({"other_kind": self.other_kind} if self.other_kind else {})

    def close(self) -> None:
        for feed in self.feeds:  # a local camera first: nothing is submitted after this
            feed.close()
        with self._wake:
            self._stop = True
            self._wake.notify()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
        for s in self._subs:
            try:
                s.undeclare()
            except Exception as e:  # the session may be gone already
                log.debug("camera undeclare: %s", e)

