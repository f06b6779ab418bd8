"""The ROS 2 messages recordings and the live view carry, as CDR bytes, and their ``ros2msg`` schemas.

Messages are serialised by rosbags' Humble typestore (no ROS installation). A schema's text is the
message definition followed by every type it uses, each after a ``====...`` line and ``MSG: pkg/Name``
(what ``ros2 bag`` writes and what Foxglove and mcap-ros2-support parse).

Frames: ``world`` is the fixed frame; odometry and TF give ``world -> <robot root link>`` (the base),
the robot's joints give its links, and every object has a frame of its own name.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from rlgp_exec.hal.ros_codec import _ser, _stamp, _store, _t
from rlgp_exec.robot.model import FloatArray

__all__ = [
    "WORLD",
    "RosSchema",
    "joint_state",
    "odometry",
    "ros_schema",
    "string",
    "tf_message",
]

WORLD = "world"  # the fixed frame of recordings and of the live view


@dataclass(frozen=True)
class RosSchema:
    """A channel's schema: ``name`` (``pkg/msg/Name``), encoding ``ros2msg``, ``text`` (the definition)."""

    name: str
    text: str
    encoding: str = "ros2msg"
    message_encoding: str = "cdr"


@cache
def ros_schema(typename: str) -> RosSchema:
    """The ``ros2msg`` schema of ``typename`` (e.g. ``sensor_msgs/msg/JointState``), dependencies included."""
    text, _ = _store().generate_msgdef(typename, ros_version=2)
    return RosSchema(typename, text)


def _header(t: float, frame: str) -> Any:
    return _t("std_msgs/msg/Header")(stamp=_stamp(t), frame_id=frame)


def _quaternions(R: FloatArray) -> FloatArray:
    """Unit quaternions (N, 4) as x, y, z, w of rotation matrices (N, 3, 3)."""
    return np.asarray(Rotation.from_matrix(R).as_quat(), dtype=float).reshape(-1, 4)


def joint_state(t: float, names: Sequence[str], q: ArrayLike, dq: ArrayLike) -> bytes:
    """``sensor_msgs/msg/JointState`` at ``t`` [s]: positions [rad or m] and velocities of ``names``."""
    msg = _t("sensor_msgs/msg/JointState")(
        header=_header(t, ""),
        name=list(names),
        position=np.asarray(q, dtype=np.float64),
        velocity=np.asarray(dq, dtype=np.float64),
        effort=np.zeros(0, dtype=np.float64),
    )
    return _ser(msg, "sensor_msgs/msg/JointState")


def odometry(
    t: float, child: str, base: ArrayLike, velocity: ArrayLike = (0.0, 0.0, 0.0)
) -> bytes:
    """``nav_msgs/msg/Odometry`` of the base ``child`` in ``world``: pose ``base`` = (x, y [m], yaw [rad]),
    twist ``velocity`` = (vx, vy [m/s], wz [rad/s]) in the base frame."""
    x, y, yaw = (float(v) for v in np.asarray(base, dtype=float).reshape(3))
    vx, vy, wz = (float(v) for v in np.asarray(velocity, dtype=float).reshape(3))
    V, P, Q = _t("geometry_msgs/msg/Vector3"), _t("geometry_msgs/msg/Point"), _t("geometry_msgs/msg/Quaternion")
    pose = _t("geometry_msgs/msg/Pose")(
        position=P(x=x, y=y, z=0.0), orientation=Q(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
    )
    twist = _t("geometry_msgs/msg/Twist")(linear=V(x=vx, y=vy, z=0.0), angular=V(x=0.0, y=0.0, z=wz))
    msg = _t("nav_msgs/msg/Odometry")(
        header=_header(t, WORLD),
        child_frame_id=child,
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=np.zeros(36)),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(twist=twist, covariance=np.zeros(36)),
    )
    return _ser(msg, "nav_msgs/msg/Odometry")


def tf_message(t: float, transforms: Sequence[tuple[str, str, FloatArray]]) -> bytes:
    """``tf2_msgs/msg/TFMessage`` at ``t`` [s]: one ``(parent, child, T_parent_child (4, 4))`` each."""
    V, Q = _t("geometry_msgs/msg/Vector3"), _t("geometry_msgs/msg/Quaternion")
    Tr, Ts = _t("geometry_msgs/msg/Transform"), _t("geometry_msgs/msg/TransformStamped")
    out = []
    stamp = _stamp(t)
    H = _t("std_msgs/msg/Header")
    if transforms:
        Ts_all = np.stack([T for _, _, T in transforms])
        quats = _quaternions(Ts_all[:, :3, :3])
        for (parent, child, _), T, (qx, qy, qz, qw) in zip(transforms, Ts_all, quats, strict=True):
            out.append(
                Ts(
                    header=H(stamp=stamp, frame_id=parent),
                    child_frame_id=child,
                    transform=Tr(
                        translation=V(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
                        rotation=Q(x=float(qx), y=float(qy), z=float(qz), w=float(qw)),
                    ),
                )
            )
    return _ser(_t("tf2_msgs/msg/TFMessage")(transforms=out), "tf2_msgs/msg/TFMessage")


def string(text: str) -> bytes:
    """``std_msgs/msg/String`` (the robot's URDF on ``/robot_description``)."""
    return _ser(_t("std_msgs/msg/String")(data=text), "std_msgs/msg/String")

