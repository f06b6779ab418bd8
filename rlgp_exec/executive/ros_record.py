"""What a viewer reads from the executive's records: ROS 2 messages and Foxglove scene entities.

:class:`RosView` turns the executive's records (``/scene``, ``/robot_state``, ``/detections``,
``/plan``, as the recorder receives them) into the channels of :data:`ROS_CHANNELS`:

- ``/robot_description`` (``std_msgs/String``, the URDF) and ``/tf_static`` (fixed joints) with the
  first ``/scene``, ``/scene_entities`` (fixtures, drawers, regions, objects) with each;
- ``/joint_states``, ``/odom`` (the base in ``world``) and ``/tf`` (``world -> base`` and every moving
  joint's ``T_parent_child`` by FK) with each ``/robot_state``;
- ``/tf`` (``world -> object``) with each ``/scene`` and ``/detections``, and the drawers' entities
  when a sensed opening changes;
- ``/plan_path`` (the planned base and tool paths) with each ``/plan``.

Headers are stamped with the record's wall time, the recording's clock, so a viewer's timeline and its
TF lookups agree (the robot's own clock stays in ``/robot_state``). Nothing is derived before the first
``/scene`` (it names the robot).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from rlgp_exec.executive import ros_messages as rm
from rlgp_exec.executive import scene_entities as se
from rlgp_exec.executive.robot_tf import RobotTf
from rlgp_exec.executive.world import drawer_openings
from rlgp_exec.robot.model import FloatArray, load_robot
from rlgp_exec.scene import Scene, scene_from_dict

__all__ = ["ROS_CHANNELS", "Channel", "RosView"]

DRAWER_EPS = 1e-3  # [m] a sensed opening changing less than this does not redraw its drawer


@dataclass(frozen=True)
class Channel:
    """A derived channel: its schema (name, encoding, definition bytes) and message encoding."""

    topic: str
    schema_name: str
    schema_encoding: str
    schema_data: bytes
    message_encoding: str


def _ros(topic: str, typename: str) -> Channel:
    s = rm.ros_schema(typename)
    return Channel(topic, s.name, s.encoding, s.text.encode(), s.message_encoding)


ROS_CHANNELS: Mapping[str, Channel] = {
    c.topic: c
    for c in (
        _ros("/robot_description", "std_msgs/msg/String"),
        _ros("/tf_static", "tf2_msgs/msg/TFMessage"),
        _ros("/tf", "tf2_msgs/msg/TFMessage"),
        _ros("/joint_states", "sensor_msgs/msg/JointState"),
        _ros("/odom", "nav_msgs/msg/Odometry"),
        Channel("/scene_entities", se.SCHEMA.name, se.SCHEMA.encoding, bytes(se.SCHEMA.data), "protobuf"),
        Channel("/plan_path", se.SCHEMA.name, se.SCHEMA.encoding, bytes(se.SCHEMA.data), "protobuf"),
    )
}


def _matrix(T: Any) -> FloatArray:
    a = np.asarray(T, dtype=float)
    if a.shape != (4, 4) or not np.all(np.isfinite(a)):
        raise ValueError(f"expected a finite 4x4 pose, got shape {a.shape}")
    return a


class RosView:
    """The derived messages of each record (module docstring); not thread-safe (the recorder locks)."""

    def __init__(self) -> None:
        self.scene: Scene | None = None
        self.robot: RobotTf | None = None
        self.openings: dict[str, float] = {}

    def derive(self, topic: str, data: Mapping[str, Any], t: float) -> list[tuple[str, bytes]]:
        """``(channel, payload)`` for the record ``data`` on ``topic`` at wall time ``t`` [s]; raises
        ValueError, KeyError or TypeError on a record it cannot read (the recorder logs and goes on)."""
        if topic == "/scene":
            return self._scene(data, t)
        if self.scene is None or self.robot is None:
            return []
        if topic == "/robot_state":
            return self._state(data, t)
        if topic == "/detections":
            return self._detections(data.get("poses", {}), t)
        if topic == "/plan":
            paths = [ph["path"] for ph in data.get("phases", [])]
            return [("/plan_path", se.plan_update(t, self.robot, paths))]
        return []

    def _scene(self, data: Mapping[str, Any], t: float) -> list[tuple[str, bytes]]:
        # the viewer draws the world as sensed: the file's random ranges (which rule out an object in a
        # drawer) are no part of it
        movables = [{k: v for k, v in o.items() if k != "random"} for o in data.get("object", [])]
        scene = scene_from_dict({**data, "object": movables}, "recorded scene")
        out = []
        if self.robot is None or self.robot.model.name != scene.robot.name:  # the robot: once
            self.robot = RobotTf(load_robot(scene.robot.name))
            out += [("/robot_description", rm.string(self.robot.description)),
                    ("/tf_static", rm.tf_message(t, self.robot.static_transforms()))]
        self.scene = scene
        robot = self.robot
        q = robot.model.home(scene.robot.base, scene.robot.joints)
        objects = [(rm.WORLD, o.name, o.T) for o in scene.objects]
        return [
            *out,
            ("/scene_entities", se.scene_update(t, scene, self.openings)),
            ("/tf", rm.tf_message(t, [*robot.transforms(q), *objects])),
        ]

    def _state(self, d: Mapping[str, Any], t: float) -> list[tuple[str, bytes]]:
        assert self.robot is not None
        robot = self.robot
        names, values = list(d["names"]), np.asarray(d["q"], dtype=float)
        base = np.asarray(d["base"], dtype=float)
        if values.shape != (len(names),) or base.shape != (3,):
            raise ValueError(f"robot state: {len(names)} names, q of shape {values.shape}, base of shape {base.shape}")
        dq = np.asarray(d.get("dq", np.zeros(len(names))), dtype=float)
        q = robot.q(base, names, values)
        return [
            ("/joint_states", rm.joint_state(t, names, values, dq if dq.shape == values.shape else np.zeros(0))),
            ("/odom", rm.odometry(t, robot.root, base, d.get("base_velocity", (0.0, 0.0, 0.0)))),
            ("/tf", rm.tf_message(t, robot.transforms(q))),
        ]

    def _detections(self, poses: Mapping[str, Any], t: float) -> list[tuple[str, bytes]]:
        assert self.scene is not None
        names = {o.name for o in self.scene.objects}
        sensed = {n: _matrix(T) for n, T in poses.items()}
        out = []
        objects = [(rm.WORLD, n, T) for n, T in sensed.items() if n in names]
        if objects:
            out.append(("/tf", rm.tf_message(t, objects)))
        moved = {c: o for c, o in drawer_openings(self.scene, sensed).items()
                 if abs(o - self.openings.get(c, 0.0)) >= DRAWER_EPS}
        if moved:
            self.openings.update(moved)
            out.append(("/scene_entities", se.drawer_update(t, self.scene, moved)))
        return out
