"""The live view over Foxglove's WebSocket protocol, checked with a client written here (no WebSocket
client library is installed): the server advertises the viewer's channels with their ROS 2 and
Foxglove schemas, and a subscriber receives the robot's messages as the executive records them."""

from __future__ import annotations

import base64
import json
import logging
import os
import socket
import struct
import time
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.cli import build_parser
from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.foxglove_live import CLIENT_POLLER_LOGGER, LATCH_S, ClientDropAtInfo, FoxgloveLive, Tee
from rlgp_exec.executive.recorder import Recorder, read_recording
from rlgp_exec.executive.ros_record import ROS_CHANNELS
from rlgp_exec.hal.ros_codec import _store
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene, scene_to_dict

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "shelf_hsr.toml"


class WsClient:
    """A minimal WebSocket client (RFC 6455: handshake, masked frames out, unfragmented frames in)."""

    def __init__(self, port: int, protocol: str = "foxglove.sdk.v1") -> None:
        self.sock = socket.create_connection(("127.0.0.1", port), timeout=5.0)
        key = base64.b64encode(os.urandom(16)).decode()
        self.sock.sendall(
            f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
            f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\nSec-WebSocket-Protocol: {protocol}\r\n\r\n"
            .encode()
        )
        head = b""
        while b"\r\n\r\n" not in head:
            head += self.sock.recv(1)
        assert head.startswith(b"HTTP/1.1 101"), head
        assert f"sec-websocket-protocol: {protocol}".encode() in head.lower(), head

    def _read(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            assert chunk, "the server closed the connection"
            out += chunk
        return out

    def recv(self) -> tuple[int, bytes]:
        b0, b1 = self._read(2)
        n = b1 & 0x7F
        if n == 126:
            n = struct.unpack(">H", self._read(2))[0]
        elif n == 127:
            n = struct.unpack(">Q", self._read(8))[0]
        assert b0 & 0x80, "a fragmented frame"
        return b0 & 0x0F, self._read(n)

    def send_json(self, msg: dict) -> None:
        data, mask = json.dumps(msg).encode(), os.urandom(4)
        assert len(data) < 126
        self.sock.sendall(bytes([0x81, 0x80 | len(data)]) + mask + bytes(c ^ mask[i % 4] for i, c in enumerate(data)))

    def until(self, pred, timeout_s: float = 5.0):
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            op, data = self.recv()
            if (r := pred(op, data)) is not None:
                return r
        raise AssertionError("not received in time")


def _text(op: str):
    return lambda o, d: json.loads(d) if o == 1 and json.loads(d).get("op") == op else None


@pytest.fixture
def live():
    with FoxgloveLive(port=0) as lv:
        yield lv


def _feed(sink, n: int = 5) -> None:
    scene = load_scene(SCENE)
    model = load_robot("hsr")
    names = list(model.joint_names[3:])
    sink.write("/scene", scene_to_dict(scene))
    q0 = model.home(scene.robot.base)
    sink.write("/plan", {"phases": [{"path": np.linspace(q0, q0 + 0.05, 4)}]})
    t0 = time.time()
    for k in range(n):
        state = {"stamp": 0.1 * k, "names": names, "q": q0[3:] + 0.01 * k, "dq": np.zeros(len(names)),
                 "base": [0.1 * k, 0.0, 0.0], "base_velocity": [0.0, 0.0, 0.0]}
        sink.write("/robot_state", state, t0 + 0.1 * k)


def test_channels_are_advertised_with_their_schemas_and_messages_reach_a_subscriber(live):
    client = WsClient(live.port)
    info = client.until(_text("serverInfo"))
    assert info["name"] == "rlgp-exec"
    adv = client.until(_text("advertise"))
    channels = {c["topic"]: c for c in adv["channels"]}
    assert set(channels) == set(ROS_CHANNELS)
    js = channels["/joint_states"]
    assert (js["encoding"], js["schemaName"], js["schemaEncoding"]) == ("cdr", "sensor_msgs/msg/JointState", "ros2msg")
    assert js["schema"] == _store().generate_msgdef("sensor_msgs/msg/JointState", ros_version=2)[0]
    assert channels["/scene_entities"]["schemaName"] == "foxglove.SceneUpdate"
    subs = {1: "/joint_states", 2: "/robot_description", 3: "/tf"}
    client.send_json({"op": "subscribe", "subscriptions": [{"id": i, "channelId": channels[t]["id"]}
                                                           for i, t in subs.items()]})
    time.sleep(0.3)  # the subscription reaches the server before the messages
    _feed(live)
    got: dict[str, list[bytes]] = {}

    def message(op: int, data: bytes):
        if op == 2 and data[0] == 0x01:  # binary messageData: subscription id, log time, payload
            sub_id, _ = struct.unpack_from("<IQ", data, 1)
            got.setdefault(subs[sub_id], []).append(data[13:])
        done = len(got.get("/joint_states", [])) == 5 and len(got.get("/tf", [])) == 6  # the scene's, 5 states'
        return True if done and "/robot_description" in got else None

    client.until(message)
    model = load_robot("hsr")
    states = [_store().deserialize_cdr(p, "sensor_msgs/msg/JointState") for p in got["/joint_states"]]
    assert [list(s.name) for s in states] == [list(model.joint_names[3:])] * 5
    assert np.allclose(states[-1].position, model.home()[3:] + 0.04)
    urdf = _store().deserialize_cdr(got["/robot_description"][0], "std_msgs/msg/String").data
    assert urdf.startswith("<robot") and "base_x_link" not in urdf
    tf = _store().deserialize_cdr(got["/tf"][-1], "tf2_msgs/msg/TFMessage")
    base = next(t for t in tf.transforms if t.child_frame_id == "base_footprint")
    assert base.header.frame_id == "world" and abs(base.transform.translation.x - 0.4) < 1e-9


def test_a_client_connecting_late_gets_the_robot_and_the_scene_again(live):
    _feed(live, n=1)
    client = WsClient(live.port)
    channels = {c["topic"]: c["id"] for c in client.until(_text("advertise"))["channels"]}
    client.send_json({"op": "subscribe", "subscriptions": [{"id": 7, "channelId": channels["/scene_entities"]}]})
    payload = client.until(lambda o, d: d[13:] if o == 2 and d[0] == 1 else None, timeout_s=3 * LATCH_S + 2)
    assert b"object/block" in payload and b"fixture/" in payload


def test_a_tee_records_and_serves_the_same_records(live, tmp_path):
    with Recorder(tmp_path / "run.mcap") as rec:
        _feed(Tee(rec, live))
    r = read_recording(tmp_path / "run.mcap")
    assert [t for t, _, _ in r.messages] == ["/scene", "/plan"] + ["/robot_state"] * 5
    assert r.derived["/joint_states"] == 5


def test_a_busy_port_is_refused_clearly_and_the_option_parses(live):
    with pytest.raises(RlgpError, match=rf"--foxglove: cannot serve on 127\.0\.0\.1:{live.port}"):
        FoxgloveLive(port=live.port)
    with pytest.raises(RlgpError, match=r"a TCP port is 0\.\.65535"):
        FoxgloveLive(port=70000)
    parse = build_parser().parse_args
    assert parse(["run", "s.toml", "--foxglove"]).foxglove == 8765
    assert parse(["run", "s.toml", "--foxglove", "9000"]).foxglove == 9000
    assert parse(["run", "s.toml"]).foxglove is None and parse(["demo", "--foxglove"]).foxglove == 8765
    for bad in ("0", "70000", "x"):
        with pytest.raises(SystemExit) as e:
            parse(["run", "s.toml", "--foxglove", bad])
        assert e.value.code == 2


def test_the_cameras_images_are_served_and_recorded_on_the_robots_topic(live, tmp_path):
    from rlgp_exec.executive.camera_record import COMPRESSED, INFO
    from rlgp_exec.hal import ros_image as ri
    from rlgp_exec.hal.ros_codec import Rejected

    topic = "/hsrb/head_rgbd_sensor/rgb/image_rect_color/compressed"
    image = ri.encode_compressed(12.5, "head_rgbd_sensor_rgb_frame", np.full((48, 64, 3), 90, np.uint8))
    info = ri.encode_camera_info(12.5, "head_rgbd_sensor_rgb_frame", 64, 48, np.eye(3))
    client = WsClient(live.port)
    client.until(_text("advertise"))
    with Recorder(tmp_path / "run.mcap") as rec:
        tee = Tee(rec, live)
        tee.write_ros("/hsrb/head_rgbd_sensor/rgb/camera_info", INFO, info, time.time())
        tee.write_ros(topic, COMPRESSED, image, time.time())
        adv = client.until(lambda o, d: next((c for c in json.loads(d).get("channels", []) if c["topic"] == topic),
                                             None) if o == 1 else None)
        assert (adv["encoding"], adv["schemaName"], adv["schemaEncoding"]) == ("cdr", COMPRESSED, "ros2msg")
        client.send_json({"op": "subscribe", "subscriptions": [{"id": 3, "channelId": adv["id"]}]})
        time.sleep(0.3)  # the subscription reaches the server before the message
        tee.write_ros(topic, COMPRESSED, image, time.time())
        payload = client.until(lambda o, d: d[13:] if o == 2 and d[0] == 1 else None)
    assert payload == image
    frame = ri.parse_compressed(payload)
    assert not isinstance(frame, Rejected) and frame.size == (64, 48)
    r = read_recording(tmp_path / "run.mcap")
    assert dict(r.derived) == {topic: 2, "/hsrb/head_rgbd_sensor/rgb/camera_info": 1} and r.messages == ()
    with pytest.raises(RlgpError, match="only"):
        live.write_ros("/tf", COMPRESSED, image, time.time())


def test_a_viewer_dropping_its_connection_is_an_info_event_not_an_error(live, caplog):
    """A viewer that goes away without a close frame (a closed laptop, a reset link): the SDK's receive
    error reaches the log as INFO; the server keeps serving the next viewer."""
    with caplog.at_level(logging.INFO, logger=CLIENT_POLLER_LOGGER):
        client = WsClient(live.port)
        client.until(_text("serverInfo"))
        client.sock.setsockopt(socket.SOL_SOCKET, socket.SO_LINGER, struct.pack("ii", 1, 0))
        client.sock.close()  # SO_LINGER 0: a TCP reset, no closing handshake
        end = time.monotonic() + 5.0
        while time.monotonic() < end and not any("Error receiving" in r.getMessage() for r in caplog.records):
            time.sleep(0.05)
        WsClient(live.port).until(_text("serverInfo"))
    drops = [r for r in caplog.records if r.name == CLIENT_POLLER_LOGGER and "Error receiving" in r.getMessage()]
    assert drops and all(r.levelno == logging.INFO for r in drops), [(r.levelname, r.getMessage()) for r in drops]
    assert not [r for r in caplog.records if r.name.startswith("foxglove") and r.levelno >= logging.ERROR]


def test_other_errors_of_the_client_poller_stay_errors():
    f = ClientDropAtInfo()
    rec = logging.LogRecord(CLIENT_POLLER_LOGGER, logging.ERROR, __file__, 1, "Error receiving from client "
                            "127.0.0.1:1: Protocol error: invalid opcode", None, None)
    assert f.filter(rec) and rec.levelno == logging.ERROR
    rec = logging.LogRecord(CLIENT_POLLER_LOGGER, logging.ERROR, __file__, 1, "Error receiving from client "
                            "127.0.0.1:1: IO error: Connection reset by peer (os error 104)", None, None)
    f.filter(rec)
    assert rec.levelno == logging.INFO and rec.levelname == "INFO"
