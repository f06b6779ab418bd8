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


def test_one_off_commands_wait_for_room_and_streams_drop() -> None:
    """A congested link drops a state or a setpoint (the next one replaces it), never the e-stop or a
    gripper command: nothing sends those again (a dropped open left a block in the hand, 12 cm up)."""
    import socket

    import zenoh

    from rlgp_exec.hal import make_backend
    from rlgp_exec.hal.zenoh_keys import session_config

    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        ep = f"tcp/127.0.0.1:{sock.getsockname()[1]}"
    peer = zenoh.open(session_config(listen=ep))
    hal = make_backend("zenoh", endpoint=ep)
    try:
        hal.configure()
        pubs = hal._pubs  # the backend's publishers by topic
        assert set(zenoh_keys.ONE_OFF_COMMANDS) < set(pubs)
        for name, pub in pubs.items():
            cc = zenoh.CongestionControl
            want = cc.BLOCK if name in zenoh_keys.ONE_OFF_COMMANDS else cc.DROP
            assert pub.congestion_control == want, name
            assert pub.priority == zenoh.Priority.REAL_TIME, name
    finally:
        hal.shutdown()
        peer.close()
