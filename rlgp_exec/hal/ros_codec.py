"""ROS 2 messages as CDR bytes without ROS (rosbags, Humble types): encode, and decode defensively.

Decoders never raise on bad bytes: they return a :class:`Rejected` with the reason (payload too big,
no CDR header, truncated, wrong message type, NaN, inconsistent lengths), so a receiver can count and
log it and carry on.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from rosbags.typesys import Stores, get_typestore

from rlgp_exec.hal.types import FloatArray, HalError, JointSetpoint

__all__ = [
    "MAX_PAYLOAD",
    "Rejected",
    "decode",
    "encode_bool",
    "encode_float64",
    "encode_joint_state",
    "encode_odometry",
    "encode_string",
    "encode_trajectory",
    "encode_transforms",
    "encode_twist",
    "parse_joint_state",
    "parse_odometry",
    "parse_stamped_transforms",
    "parse_trajectory",
    "parse_transforms",
    "parse_twist",
    "prepare",
]

MAX_PAYLOAD = 64 * 1024  # [bytes] anything larger is not one of our messages
_CDR_HEADERS = (b"\x00\x01\x00\x00", b"\x00\x00\x00\x00")  # CDR_LE, CDR_BE (options 0)


@dataclass(frozen=True)
class Rejected:
    key: str  # short reason class, used as a counter key
    reason: str

    def __bool__(self) -> bool:
        return False


# every type sent or received: rosbags generates each one's (de)serialisers on first use, tens of ms of
# GIL-held work that, done in the subscriber threads at the first setpoints, delayed them by 0.2-0.4 s
WIRE_TYPES = (
    "builtin_interfaces/msg/Time",
    "geometry_msgs/msg/TransformStamped",
    "geometry_msgs/msg/Twist",
    "nav_msgs/msg/Odometry",
    "sensor_msgs/msg/CameraInfo",
    "sensor_msgs/msg/CompressedImage",
    "sensor_msgs/msg/Image",
    "sensor_msgs/msg/JointState",
    "std_msgs/msg/Bool",
    "std_msgs/msg/Float64",
    "std_msgs/msg/String",
    "tf2_msgs/msg/TFMessage",
    "trajectory_msgs/msg/JointTrajectory",
)


def _nested(store: Any, desc: Any) -> set[str]:
    """The message type names inside a field description (nested, arrays and sequences of them)."""
    if isinstance(desc, str):
        return {desc} if desc in store.fielddefs else set()
    if isinstance(desc, tuple | list):
        return set().union(*(_nested(store, d) for d in desc))
    return set()


@lru_cache(maxsize=1)
def _store() -> Any:
    store = get_typestore(Stores.ROS2_HUMBLE)
    todo, done = list(WIRE_TYPES), set()
    while todo:
        name = todo.pop()
        if name not in done:
            done.add(name)
            store.get_msgdef(name)
            todo.extend(_nested(store, store.fielddefs[name][1]))
    return store


def prepare() -> None:
    """Generate the message codecs now (set-up, before any subscriber runs), not on the first message."""
    _store()


def _t(name: str) -> Any:
    return _store().types[name]


def _ser(msg: Any, typename: str) -> bytes:
    return bytes(_store().serialize_cdr(msg, typename))


def _stamp(t: float) -> Any:
    # rounded as a whole: t = 5.9999999997 is 6 s 0 ns (the fraction alone rounds to 1e9 ns: 5 s 0 ns)
    sec, ns = divmod(round(t * 1e9), 1_000_000_000)
    return _t("builtin_interfaces/msg/Time")(sec=int(sec), nanosec=int(ns))


def _header(t: float, frame: str = "") -> Any:
    return _t("std_msgs/msg/Header")(stamp=_stamp(t), frame_id=frame)


# ---------------------------------------------------------------------- encoders
def encode_joint_state(stamp: float, names: Sequence[str], q: ArrayLike, dq: ArrayLike) -> bytes:
    msg = _t("sensor_msgs/msg/JointState")(
        header=_header(stamp),
        name=list(names),
        position=np.asarray(q, dtype=np.float64),
        velocity=np.asarray(dq, dtype=np.float64),
        effort=np.zeros(0, dtype=np.float64),
    )
    return _ser(msg, "sensor_msgs/msg/JointState")


def _vec3(x: float, y: float, z: float) -> Any:
    return _t("geometry_msgs/msg/Vector3")(x=float(x), y=float(y), z=float(z))


def _twist(vx: float, vy: float, wz: float) -> Any:
    return _t("geometry_msgs/msg/Twist")(linear=_vec3(vx, vy, 0.0), angular=_vec3(0.0, 0.0, wz))


def encode_odometry(stamp: float, x: float, y: float, yaw: float, vx: float, vy: float, wz: float) -> bytes:
    P, Q = _t("geometry_msgs/msg/Point"), _t("geometry_msgs/msg/Quaternion")
    pose = _t("geometry_msgs/msg/Pose")(
        position=P(x=float(x), y=float(y), z=0.0),
        orientation=Q(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
    )
    msg = _t("nav_msgs/msg/Odometry")(
        header=_header(stamp, "odom"),
        child_frame_id="base_footprint",
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=pose, covariance=np.zeros(36)),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(twist=_twist(vx, vy, wz), covariance=np.zeros(36)),
    )
    return _ser(msg, "nav_msgs/msg/Odometry")


def encode_trajectory(sp: JointSetpoint, time_from_start: float, stamp: float = 0.0) -> bytes:
    sec = math.floor(time_from_start)
    pt = _t("trajectory_msgs/msg/JointTrajectoryPoint")(
        positions=np.asarray(sp.q, dtype=np.float64),
        velocities=np.asarray(sp.dq, dtype=np.float64),
        accelerations=np.zeros(0),
        effort=np.zeros(0),
        time_from_start=_t("builtin_interfaces/msg/Duration")(sec=int(sec), nanosec=int((time_from_start - sec) * 1e9)),
    )
    msg = _t("trajectory_msgs/msg/JointTrajectory")(header=_header(stamp), joint_names=list(sp.names), points=[pt])
    return _ser(msg, "trajectory_msgs/msg/JointTrajectory")


def encode_twist(vx: float, vy: float, wz: float) -> bytes:
    return _ser(_twist(vx, vy, wz), "geometry_msgs/msg/Twist")


def encode_bool(value: bool) -> bytes:
    return _ser(_t("std_msgs/msg/Bool")(data=bool(value)), "std_msgs/msg/Bool")


def encode_float64(value: float) -> bytes:
    return _ser(_t("std_msgs/msg/Float64")(data=float(value)), "std_msgs/msg/Float64")


def encode_string(value: str) -> bytes:
    return _ser(_t("std_msgs/msg/String")(data=value), "std_msgs/msg/String")


# ---------------------------------------------------------------------- decoders
def decode(payload: bytes, typename: str, limit: int = MAX_PAYLOAD) -> Any:
    """The message in ``payload`` (at most ``limit`` bytes), or :class:`Rejected`. Never raises on bad bytes."""
    n = len(payload)
    if n > limit:
        return Rejected("too_large", f"{typename}: payload of {n} bytes > {limit}")
    if n < 4 or payload[:4] not in _CDR_HEADERS:
        return Rejected("no_cdr_header", f"{typename}: no CDR encapsulation header in {payload[:4]!r} ({n} bytes)")
    try:
        return _store().deserialize_cdr(payload, typename)
    except Exception as e:  # rosbags raises SerdeError, but corrupt bytes can surface as anything
        return Rejected("malformed", f"{typename}: cannot decode {n} bytes: {type(e).__name__}: {e}")


def _finite(a: Any) -> bool:
    return bool(np.all(np.isfinite(np.asarray(a, dtype=float))))


def parse_joint_state(payload: bytes) -> tuple[float, tuple[str, ...], np.ndarray, np.ndarray] | Rejected:
    """(stamp [s], names, q, dq) from a sensor_msgs/JointState payload."""
    m = decode(payload, "sensor_msgs/msg/JointState")
    if isinstance(m, Rejected):
        return m
    names = tuple(m.name)
    q, dq = np.asarray(m.position, dtype=float), np.asarray(m.velocity, dtype=float)
    if len(q) != len(names) or len(dq) not in (0, len(names)):
        return Rejected("inconsistent", f"JointState: {len(names)} names, {len(q)} positions, {len(dq)} velocities")
    if len(set(names)) != len(names):
        return Rejected("inconsistent", f"JointState: duplicate names {list(names)}")
    if not (_finite(q) and _finite(dq)):
        return Rejected("non_finite", "JointState: NaN/inf position or velocity")
    stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
    return stamp, names, q, (dq if len(dq) else np.zeros(len(names)))


def parse_odometry(payload: bytes) -> tuple[float, tuple[float, float, float], tuple[float, float, float]] | Rejected:
    """(stamp, (x, y, yaw), (vx, vy, wz) base frame) from a nav_msgs/Odometry payload."""
    m = decode(payload, "nav_msgs/msg/Odometry")
    if isinstance(m, Rejected):
        return m
    p, o, t = m.pose.pose.position, m.pose.pose.orientation, m.twist.twist
    vals = [p.x, p.y, o.x, o.y, o.z, o.w, t.linear.x, t.linear.y, t.angular.z]
    if not _finite(vals):
        return Rejected("non_finite", "Odometry: NaN/inf pose or twist")
    norm = math.sqrt(o.x**2 + o.y**2 + o.z**2 + o.w**2)
    if abs(norm - 1.0) > 1e-3:
        return Rejected("invalid", f"Odometry: orientation is not a unit quaternion (|q| = {norm:.4f})")
    yaw = math.atan2(2 * (o.w * o.z + o.x * o.y), 1 - 2 * (o.y**2 + o.z**2))
    stamp = m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
    return stamp, (p.x, p.y, yaw), (t.linear.x, t.linear.y, t.angular.z)


def parse_trajectory(payload: bytes) -> JointSetpoint | Rejected:
    """The single point of a streamed trajectory_msgs/JointTrajectory as a setpoint."""
    m = decode(payload, "trajectory_msgs/msg/JointTrajectory")
    if isinstance(m, Rejected):
        return m
    if len(m.points) != 1:
        return Rejected("inconsistent", f"JointTrajectory: expected exactly 1 point (streaming), got {len(m.points)}")
    names, pt = tuple(m.joint_names), m.points[0]
    q, dq = np.asarray(pt.positions, dtype=float), np.asarray(pt.velocities, dtype=float)
    if not names or len(set(names)) != len(names):
        return Rejected("inconsistent", f"JointTrajectory: empty or duplicate joint names {list(names)}")
    if len(q) != len(names) or len(dq) not in (0, len(names)):
        return Rejected(
            "inconsistent", f"JointTrajectory: {len(names)} names, {len(q)} positions, {len(dq)} velocities"
        )
    if not (_finite(q) and _finite(dq)):
        return Rejected("non_finite", f"JointTrajectory: NaN/inf in positions/velocities for {list(names)}")
    return JointSetpoint(names, q, dq if len(dq) else None)


def parse_twist(payload: bytes) -> tuple[float, float, float] | Rejected:
    m = decode(payload, "geometry_msgs/msg/Twist")
    if isinstance(m, Rejected):
        return m
    v = (m.linear.x, m.linear.y, m.angular.z)
    if not _finite([*v, m.linear.z, m.angular.x, m.angular.y]):
        return Rejected("non_finite", "Twist: NaN/inf component")
    if any(abs(c) > 1e-9 for c in (m.linear.z, m.angular.x, m.angular.y)):
        return Rejected("invalid", "Twist: a planar base takes linear.x, linear.y and angular.z only")
    return v


def encode_transforms(stamp: float, T_parent_child: dict[str, FloatArray], parent: str = "map") -> bytes:
    """tf2_msgs/TFMessage: one transform (4, 4) per child frame, all from ``parent``."""
    # local: SciPy's rotations (~0.7 s) load only for transforms
    from scipy.spatial.transform import Rotation

    tfs = []
    for name, T in T_parent_child.items():
        x, y, z, w = Rotation.from_matrix(T[:3, :3]).as_quat()
        tfs.append(
            _t("geometry_msgs/msg/TransformStamped")(
                header=_header(stamp, parent),
                child_frame_id=name,
                transform=_t("geometry_msgs/msg/Transform")(
                    translation=_vec3(float(T[0, 3]), float(T[1, 3]), float(T[2, 3])),
                    rotation=_t("geometry_msgs/msg/Quaternion")(x=x, y=y, z=z, w=w),
                ),
            )
        )
    return _ser(_t("tf2_msgs/msg/TFMessage")(transforms=tfs), "tf2_msgs/msg/TFMessage")


def parse_transforms(payload: bytes) -> dict[str, FloatArray]:
    """The (4, 4) transforms of a TFMessage by child frame; raises HalError naming what is wrong (bad CDR,
    a non-finite value, a quaternion that is not unit length)."""
    return parse_stamped_transforms(payload)[1]


def parse_stamped_transforms(payload: bytes) -> tuple[float, dict[str, FloatArray]]:
    """``parse_transforms`` and the oldest header stamp [s] among the transforms (-inf for none)."""
    # local: SciPy's rotations (~0.7 s) load only for transforms
    from scipy.spatial.transform import Rotation

    msg = decode(payload, "tf2_msgs/msg/TFMessage")
    if isinstance(msg, Rejected):
        raise HalError(f"TFMessage: {msg.reason}")
    out = {}
    stamp = math.inf
    for tf in msg.transforms:
        stamp = min(stamp, tf.header.stamp.sec + 1e-9 * tf.header.stamp.nanosec)
        tr, q = tf.transform.translation, tf.transform.rotation
        v = np.array([tr.x, tr.y, tr.z, q.x, q.y, q.z, q.w], float)
        if not np.all(np.isfinite(v)) or abs(np.linalg.norm(v[3:]) - 1.0) > 1e-3:
            raise HalError(f"TFMessage: bad transform for {tf.child_frame_id!r}: {v.tolist()}")
        T = np.eye(4)
        T[:3, :3] = Rotation.from_quat(v[3:]).as_matrix()
        T[:3, 3] = v[:3]
        out[str(tf.child_frame_id)] = T
    return (stamp if out else -math.inf), out
