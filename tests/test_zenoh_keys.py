"""The Zenoh key maps: each bridged key names the ROS 2 topic it carries, and a map whose ``ros2`` field
disagrees with its key is refused by name."""

from __future__ import annotations

from pathlib import Path

import pytest

from rlgp_exec.hal import zenoh_keys
from rlgp_exec.hal.types import HalError
from rlgp_exec.hal.zenoh_keys import load_key_map


@pytest.mark.parametrize("robot", ["hsr", "pr2"])
def test_bridged_keys_name_their_ros2_topic(robot: str) -> None:
    keys = load_key_map(robot, namespace="lab1")
    bridged = [t for t in keys.topics.values() if t.ros2]
    assert bridged, f"{robot}: no key names a ROS 2 topic"
    for t in bridged:
        assert t.key == f"lab1/{t.ros2[1:]}"
    # the executive's own keys travel on no ROS 2 topic
    assert keys["faults"].ros2 == ""


def test_a_ros2_field_that_is_not_the_keys_topic_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    src = (zenoh_keys.robot_dir("hsr") / "zenoh_keys.toml").read_text()
    bad = src.replace('ros2 = "/hsrb/odom"', 'ros2 = "/hsrb/odometry"')
    assert bad != src
    (tmp_path / "zenoh_keys.toml").write_text(bad)
    monkeypatch.setattr(zenoh_keys, "robot_dir", lambda robot: tmp_path)
    with pytest.raises(HalError, match=r"\[keys.odom\].ros2 '/hsrb/odometry'.*'/hsrb/odom'"):
        load_key_map("hsr")
