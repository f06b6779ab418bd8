"""The executive's world model: the scene as last sensed — object poses from an ``ObjectSource`` and the
robot's start from its measured state — ready to plan from.

Object sources (one abstract method, ``poses``):

- ``ScenePoses``: the scene file's poses; senses nothing (a dry run that trusts the file; the goal
  cannot be verified against the world and the result says so).
- ``SimMocap``: the in-process simulated robot's object poses (stands in for a motion-capture system).
- ``ZenohMocap``: object poses published on a Zenoh key as ``tf2_msgs/msg/TFMessage`` (CDR), one
  transform per object (``child_frame_id`` = object name) — what a mocap bridge publishes, and what the
  simulated robot server publishes. Poses older than ``max_age_s`` are stale and not used.
"""

from __future__ import annotations

import abc
import logging
import math
import threading
import time
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from rlgp_exec.errors import RlgpError, SceneError
from rlgp_exec.hal.ros_codec import parse_stamped_transforms
from rlgp_exec.hal.types import RobotState
from rlgp_exec.hal.zenoh_keys import exact
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene, StartState, cabinet_geometry
from rlgp_exec.scene.geometry import support_surfaces
from rlgp_exec.scene.validate import find_support

__all__ = [
    "DRAWER_CLOSED_M",
    "DRAWER_SUFFIX",
    "MOCAP_KEY",
    "ObjectSource",
    "ScenePoses",
    "SimMocap",
    "ZenohMocap",
    "carried_along",
    "drawer_openings",
    "stacks",
    "update_scene",
]

log = logging.getLogger(__name__)

MOCAP_KEY = "rlgp/mocap/objects"  # tf2_msgs/msg/TFMessage, world frame "map"
DRAWER_SUFFIX = ".drawer"  # mocap frame of a cabinet's drawer: "<cabinet>.drawer"
SNAP_Z = 0.02  # [m] a sensed object this close above/below a support surface rests on it
DRAWER_CLOSED_M = 0.01  # [m] a drawer out less than this counts as closed
DRAWER_STOP_TOL_M = 0.005  # [m] a sensed opening this far beyond a stop is the stop, not a sensor fault
HELD_MAX_M = 0.15  # [m] a held object sensed farther than this from the tool frame is not in the hand


class ObjectSource(abc.ABC):
    """Where object poses come from."""

    senses: bool = True  # False: the poses are assumptions, not observations

    @abc.abstractmethod
    def poses(self) -> dict[str, FloatArray]:
        """T_world_object (4, 4) of every object seen now (unseen objects are absent)."""

    def stamp(self) -> float | None:
        """Robot-clock time [s] of the oldest observation in ``poses()``; None when the source has no such
        clock (the file, the camera, which gates its own age)."""
        return None

    def look_for(self, names: Sequence[str], hal: Any) -> Any:
        """Look (move the robot's head through ``hal``) until ``names`` are seen; what was found, or None
        for a source that cannot look (mocap, the file)."""
        return None

    def close(self) -> None:  # noqa: B027 - optional
        pass


class ScenePoses(ObjectSource):
    senses = False

    def __init__(self, scene: Scene) -> None:
        self._poses = {o.name: o.T for o in scene.objects}

    def poses(self) -> dict[str, FloatArray]:
        return dict(self._poses)


class SimMocap(ObjectSource):
    """Poses from an in-process ``SimRobot`` (the HAL's sim backend: ``hal.sim``)."""

    def __init__(self, hal: Any) -> None:
        self._hal = hal

    def poses(self) -> dict[str, FloatArray]:
        sim = self._hal.sim
        if sim is None:
            return {}
        poses = {name: sim.object_pose(name) for name in sim.objects}
        poses.update({f"{c}{DRAWER_SUFFIX}": sim.drawer_pose(c) for c in sim.cabinets})
        return poses


class ZenohMocap(ObjectSource):
    """Subscribes to ``MOCAP_KEY`` (prefixed by ``namespace``) on an open Zenoh session."""

    def __init__(self, session: Any, namespace: str = "", max_age_s: float = 0.5) -> None:
        self.key = f"{namespace.strip('/')}/{MOCAP_KEY}" if namespace else MOCAP_KEY
        self.max_age_s = max_age_s
        self._lock = threading.Lock()
        self._poses: dict[str, FloatArray] = {}
        self._wall = -math.inf
        self._stamp = -math.inf
        self.rejected = 0
        self._sub = session.declare_subscriber(self.key, self._on_sample)

    def _on_sample(self, sample: Any) -> None:
        if not exact(sample, self.key):  # a put on a wildcard (rlgp/**) is nobody's motion capture
            self.rejected += 1
            log.warning("mocap: ignored a sample on %s (not exactly %s)", sample.key_expr, self.key)
            return
        try:
            stamp, poses = parse_stamped_transforms(sample.payload.to_bytes())
        except RlgpError as e:
            self.rejected += 1
            log.warning("mocap: %s", e)
            return
        with self._lock:
            self._poses, self._wall, self._stamp = poses, time.monotonic(), stamp

    def stamp(self) -> float | None:
        with self._lock:
            return self._stamp

    def poses(self) -> dict[str, FloatArray]:
        with self._lock:
            if time.monotonic() - self._wall > self.max_age_s:
                return {}
            return dict(self._poses)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except Exception as e:  # the session may be gone already
            log.debug("mocap undeclare: %s", e)


def drawer_openings(scene: Scene, poses: dict[str, FloatArray]) -> dict[str, float]:
    """How far [m] each cabinet's drawer is out, from its sensed ``<cabinet>.drawer`` frame (cabinets
    without one are absent), within [0, travel]: a drawer at its stop is sensed a hair beyond it."""
    out = {}
    for fx in scene.fixtures:
        T = poses.get(f"{fx.name}{DRAWER_SUFFIX}")
        if fx.kind != "drawer_cabinet" or T is None:
            continue
        g = cabinet_geometry(fx)
        sensed = float(np.dot(T[:3, 3] - g.T_world_drawer_closed[:3, 3], np.asarray(g.axis_world, float)))
        if not -DRAWER_STOP_TOL_M <= sensed <= g.travel + DRAWER_STOP_TOL_M:
            log.warning("drawer of %s sensed %.3f m out, beyond its travel [0, %.3f]: taken as at its stop",
                        fx.name, sensed, g.travel)
        out[fx.name] = float(np.clip(sensed, 0.0, g.travel))
    return out


def _snap(
    scene: Scene, name: str, x: float, y: float, z: float, height: float, openings: dict[str, float] | None = None
) -> float:
    bottom = z - height / 2
    xy = np.array([x, y])
    surfaces = support_surfaces(scene, exclude=name, openings=openings)
    near = [s.z for s in surfaces if s.contains(xy) and abs(s.z - bottom) <= SNAP_Z]
    return (max(near) + height / 2) if near else z


def update_scene(
    scene: Scene,
    model: RobotModel,
    state: RobotState | None,
    poses: dict[str, FloatArray],
    held: str | None = None,
    openings: dict[str, float] | None = None,
    T_tool_obj: FloatArray | None = None,
) -> Scene:
    """``scene`` with the robot's base and manipulator joints from ``state``, the objects at ``poses``
    (upright, resting on the surface under them, another object's top included; a drawer's floor where
    ``openings`` [m] has it; an object not sensed where what it rests on moved it, ``carried_along``) and its
    start state (``Scene.start``): the drawers out by more than DRAWER_CLOSED_M, and the object ``held``
    in the hand, rigidly at T_tool_obj: from its sensed pose and the measured arm when it is sensed,
    else ``T_tool_obj`` (the grasp as executed). Raises SceneError naming an object that is not resting
    on anything (it fell), or a held object whose grasp is unknown."""
    poses = {**carried_along(scene, poses, held), **poses}
    objects = []
    for o in scene.objects:
        T = poses.get(o.name)
        if T is None or o.name == held:
            objects.append(o)
            continue
        x, y, z, yaw = _xyz_yaw(T)
        objects.append(replace(o, pose=(x, y, z, yaw)))
    s = replace(scene, objects=tuple(objects))
    s = replace(
        s,
        objects=tuple(
            o if o.name == held else
            replace(o, pose=(o.pose[0], o.pose[1], _snap(s, o.name, *o.pose[:3], o.size[2], openings), o.pose[3]))
            for o in s.objects
        ),
    )
    if state is not None:
        joints = dict(scene.robot.joints)
        arm = model.manipulator().group
        lo, hi = model.limits.lower, model.limits.upper
        for i in model.group(arm):  # inside the limits (a measurement may sit a hair outside), to 0.1 mrad
            n = model.joint_names[i]
            if n in state.names:
                joints[n] = round(float(np.clip(state.position(n), lo[i], hi[i])), 4)
        x, y, yaw = (round(float(b), 4) for b in state.base)
        s = replace(s, robot=replace(scene.robot, base=(x, y, yaw), joints=joints))

    def fail(where: str, msg: str) -> SceneError:
        return SceneError(f"{scene.name} (sensed)", where, msg)

    out = {c: round(float(v), 4) for c, v in (openings or {}).items() if v > DRAWER_CLOSED_M}
    start = StartState(openings=tuple(sorted(out.items())))
    if held is not None:
        T_world_tool = model.fk(model.home(s.robot.base, s.robot.joints), model.manipulator().tool_frame)
        if held in poses:
            T_tool_obj = np.linalg.inv(T_world_tool) @ poses[held]
            away = float(np.linalg.norm(T_tool_obj[:3, 3]))
            if away > HELD_MAX_M:
                raise fail(f"[[object]] '{held}'", f"held, but sensed {away:.2f} m from the hand "
                                                   f"(> {HELD_MAX_M} m): it slipped out")
        if T_tool_obj is None:
            raise fail(f"[[object]] '{held}'", "held, but neither sensed nor grasped by this executive")
        x, y, z, yaw = _xyz_yaw(T_world_tool @ T_tool_obj)
        s = s.with_object_poses({held: (x, y, z, yaw)})
        start = StartState.holding(held, T_tool_obj, openings=out)
    return find_support(replace(s, start=start), fail, openings)


def stacks(scene: Scene) -> dict[str, list[str]]:
    """What rests on each object, directly or on top of others (lowest first): object -> the objects above
    it, from the ``support`` each object was found resting on (``scene.validate.find_support``)."""
    names = {o.name for o in scene.objects}
    support = {o.name: o.support for o in scene.objects if o.support in names}
    above: dict[str, list[tuple[int, str]]] = {}
    for o in scene.objects:
        x, depth = o.name, 0
        while x in support and depth < len(support):  # a support cycle cannot rest: cut at its length
            x, depth = support[x], depth + 1
            above.setdefault(x, []).append((depth, o.name))
    return {b: [n for _, n in sorted(on)] for b, on in above.items()}


def carried_along(scene: Scene, poses: dict[str, FloatArray], held: str | None = None) -> dict[str, FloatArray]:
    """T_world_object (4, 4) of the objects ``poses`` lacks (not sensed: a tag hidden, a file's assumption)
    that rest, directly or on others, on an object ``poses`` has: moved rigidly with the nearest one below
    them that was sensed, from where ``scene`` has them (a block carried or pushed with the one under it; a
    block on one the plan set down). The object in the hand, and what rests on it, are left out."""
    by_name = {o.name: o for o in scene.objects}
    out: dict[str, FloatArray] = {}
    for o in scene.objects:
        if o.name in poses or o.name == held:
            continue
        x, seen = o.support, {o.name}
        while x in by_name and x not in poses and x not in seen and x != held:
            seen.add(x)
            x = by_name[x].support
        if x in by_name and x in poses and x != held:
            out[o.name] = poses[x] @ np.linalg.inv(by_name[x].T) @ o.T
    return out


def _xyz_yaw(T: FloatArray) -> tuple[float, float, float, float]:
    return float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), math.atan2(T[1, 0], T[0, 0])
