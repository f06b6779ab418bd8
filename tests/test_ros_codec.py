"""The CDR codecs (rlgp_exec/hal/ros_codec.py) are generated at set-up: a subscriber thread that generated
one on its first message held the GIL long enough to queue the first setpoints behind it."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.types import JointSetpoint

ROOT = Path(__file__).resolve().parents[1]
WIRE_MODULES = [
    ROOT / "rlgp_exec" / "hal" / "ros_codec.py",
    ROOT / "rlgp_exec" / "hal" / "ros_image.py",
    ROOT / "rlgp_exec" / "hal" / "zenoh_backend.py",
    ROOT / "sim" / "robot_server.py",
    ROOT / "sim" / "camera_node.py",
]


def _named_types() -> set[str]:
    pat = re.compile(r'"([a-z0-9_]+/msg/[A-Za-z0-9]+)"')
    return {m for p in WIRE_MODULES for m in pat.findall(p.read_text())}


def test_prepare_generates_every_type_on_the_wire_and_the_types_inside_them():
    rc.prepare()
    cache = set(rc._store().cache)
    named = _named_types()
    assert "trajectory_msgs/msg/JointTrajectory" in named
    assert named <= cache, f"not generated at set-up: {sorted(named - cache)}"
    nested = {"trajectory_msgs/msg/JointTrajectoryPoint", "builtin_interfaces/msg/Duration", "std_msgs/msg/Header"}
    assert nested <= cache, sorted(nested - cache)


def test_a_setpoint_round_trip_after_prepare_generates_nothing():
    rc.prepare()
    before = set(rc._store().cache)
    sp = JointSetpoint(("a", "b"), [0.1, -0.2], [0.0, 0.5])
    got = rc.parse_trajectory(rc.encode_trajectory(sp, 0.01))
    assert isinstance(got, JointSetpoint) and got.names == ("a", "b")
    np.testing.assert_allclose(got.q, [0.1, -0.2])
    rc.parse_odometry(rc.encode_odometry(1.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    rc.parse_joint_state(rc.encode_joint_state(1.0, ["a"], [0.0], [0.0]))
    assert set(rc._store().cache) == before
