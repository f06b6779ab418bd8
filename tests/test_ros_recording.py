"""A real recording opens as a robot: every channel of a short sim run decodes with its own reader
(ROS 2 channels with mcap-ros2-support, scene entities as protobuf, records as JSON), and what it
says agrees with the executive's records: joint names and values, odometry, TF, the URDF."""

from __future__ import annotations

import json
import math
import threading
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap_ros2.reader import read_ros2_messages

from rlgp_exec.executive import Executive, Recorder, read_recording
from rlgp_exec.executive.replay import load_replay
from rlgp_exec.executive.ros_record import ROS_CHANNELS
from rlgp_exec.executive.world import SimMocap
from rlgp_exec.hal import make_backend
from rlgp_exec.hal.ros_codec import _store
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.config import BASE_JOINTS
from rlgp_exec.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "shelf_hsr.toml"
ROS_TOPICS = [t for t, c in ROS_CHANNELS.items() if c.message_encoding == "cdr"]


@pytest.fixture(scope="module")
def run(tmp_path_factory) -> Path:
    """A sim task cancelled 1.5 s into its first motion: planning, a plan and some motion recorded."""
    path = tmp_path_factory.mktemp("ros") / "run.mcap"
    scene = load_scene(SCENE)
    hal = make_backend("sim", scene=scene)
    hal.configure()
    try:
        with Recorder(path) as rec:
            ex = Executive(hal, scene, SimMocap(hal), recorder=rec)
            started = threading.Event()
            ex.actor.on_phase = lambda k, n: started.set()
            original, sent = hal.write_setpoint, {"n": 0}

            def counting(*a, **k):
                if started.is_set():
                    sent["n"] += 1
                    if sent["n"] == 150:
                        ex.cancel()
                return original(*a, **k)

            hal.write_setpoint = counting  # type: ignore[method-assign]
            ex.run()
    finally:
        hal.shutdown()
    return path


def _varint(b: bytes, i: int) -> tuple[int, int]:
    out = shift = 0
    while True:
        c = b[i]
        out |= (c & 0x7F) << shift
        i += 1
        shift += 7
        if not c & 0x80:
            return out, i


def _fields(b: bytes) -> list[tuple[int, bytes | int]]:
    """A protobuf message's (field number, value) pairs, length-delimited values as bytes."""
    out: list[tuple[int, bytes | int]] = []
    i = 0
    while i < len(b):
        key, i = _varint(b, i)
        num, wire = key >> 3, key & 7
        if wire == 0:
            v, i = _varint(b, i)
            out.append((num, v))
        elif wire == 2:
            n, i = _varint(b, i)
            out.append((num, b[i : i + n]))
            i += n
        elif wire in (1, 5):
            i += 8 if wire == 1 else 4
        else:
            raise AssertionError(f"wire type {wire}")
    assert i == len(b)
    return out


def _entities(payload: bytes) -> dict[str, dict[int, list[bytes | int]]]:
    """SceneUpdate.entities (field 2) by id (SceneEntity field 3), each entity's fields by number."""
    out = {}
    for num, ent in _fields(payload):
        assert num in (1, 2) and isinstance(ent, bytes)
        if num == 2:
            f: dict[int, list[bytes | int]] = {}
            for k, v in _fields(ent):
                f.setdefault(k, []).append(v)
            out[bytes(f[3][0]).decode()] = f  # type: ignore[arg-type]
    return out


def _T(tf) -> np.ndarray:
    from scipy.spatial.transform import Rotation

    r, p = tf.transform.rotation, tf.transform.translation
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat([r.x, r.y, r.z, r.w]).as_matrix()
    T[:3, 3] = (p.x, p.y, p.z)
    return T


def test_every_channel_decodes_and_the_schemas_are_the_ros2_definitions(run):
    with open(run, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        channels = {c.topic: (c, summary.schemas[c.schema_id]) for c in summary.channels.values()}
        counts: dict[str, int] = {}
        for _, ch, msg in reader.iter_messages():
            counts[ch.topic] = counts.get(ch.topic, 0) + 1
            if ch.message_encoding == "json":
                assert isinstance(json.loads(msg.data), dict)
            elif ch.message_encoding == "protobuf":
                _entities(msg.data)
    for topic in ROS_TOPICS:
        ch, schema = channels[topic]
        assert schema.encoding == "ros2msg" and ch.message_encoding == "cdr"
        assert schema.data.decode() == _store().generate_msgdef(schema.name, ros_version=2)[0]
    assert channels["/odom"][1].name == "nav_msgs/msg/Odometry"
    assert "\nMSG: std_msgs/Header\n" in channels["/odom"][1].data.decode()
    assert {channels[t][1].name for t in ("/scene_entities", "/plan_path")} == {"foxglove.SceneUpdate"}
    decoded: dict[str, int] = {}
    for m in read_ros2_messages(run, topics=ROS_TOPICS):
        decoded[m.channel.topic] = decoded.get(m.channel.topic, 0) + 1
    assert decoded == {t: counts[t] for t in ROS_TOPICS}
    assert set(counts) == set(channels) and all(counts[t] > 0 for t in ROS_CHANNELS)
    assert counts["/joint_states"] > 50 and counts["/tf"] > 50  # the motion, at the viewer's rate
    assert dict(read_recording(run).derived) == {t: counts[t] for t in ROS_CHANNELS}


def test_joint_states_odometry_and_tf_agree_with_the_robot_states(run):
    rec = read_recording(run)
    states = {round(t * 1e9): d for t, d in rec.topic("/robot_state")}
    model = load_robot("hsr")
    moving = {j.child: j.parent for j in model.urdf.joints if j.type != "fixed" and j.name not in BASE_JOINTS}
    static = {j.child: j.parent for j in model.urdf.joints if j.type == "fixed"}
    joint_states = odoms = tfs = 0
    tf_static: dict[str, np.ndarray] = {}
    for m in read_ros2_messages(run, topics=["/tf_static"]):
        tf_static.update({tf.child_frame_id: _T(tf) for tf in m.ros_msg.transforms})
        assert {tf.child_frame_id: tf.header.frame_id for tf in m.ros_msg.transforms} == static
    for m in read_ros2_messages(run, topics=["/joint_states", "/odom", "/tf"]):
        msg, t = m.ros_msg, m.log_time_ns
        stamp = msg.transforms[0].header.stamp if m.channel.topic == "/tf" else msg.header.stamp
        assert stamp.sec * 10**9 + stamp.nanosec == t  # stamped with the recording's clock
        if t not in states:
            assert m.channel.topic == "/tf"  # objects' and the scene's TF come with /detections, /scene
            continue
        d = states[t]
        if m.channel.topic == "/joint_states":
            assert list(msg.name) == d["names"]
            assert np.allclose(msg.position, d["q"]) and np.allclose(msg.velocity, d["dq"])
            joint_states += 1
        elif m.channel.topic == "/odom":
            p, o = msg.pose.pose.position, msg.pose.pose.orientation
            x, y, yaw = d["base"]
            assert (msg.header.frame_id, msg.child_frame_id) == ("world", "base_footprint")
            assert math.isclose(p.x, x, abs_tol=1e-12) and math.isclose(p.y, y, abs_tol=1e-12)
            assert math.isclose(math.atan2(2 * o.w * o.z, 1 - 2 * o.z**2), math.remainder(yaw, math.tau),
                                abs_tol=1e-9)
            odoms += 1
        else:
            T = {tf.child_frame_id: _T(tf) for tf in msg.transforms}
            parents = {tf.child_frame_id: tf.header.frame_id for tf in msg.transforms}
            assert parents == {"base_footprint": "world", **moving}
            x, y, yaw = d["base"]
            assert np.allclose(T["base_footprint"][:3, 3], (x, y, 0.0), atol=1e-9)
            # the chain of TF (moving and static) up to the hand is the robot's FK at that state
            q = model.home(d["base"], dict(zip(d["names"], d["q"], strict=True)))
            frame, chain = "hand_palm_link", np.eye(4)
            while frame != "world":
                chain = (T[frame] if frame in T else tf_static[frame]) @ chain
                frame = parents.get(frame) or static[frame]
            assert np.allclose(chain, model.fk(q, "hand_palm_link"), atol=1e-6)
            tfs += 1
    assert joint_states > 50 and odoms == joint_states and tfs == joint_states


def test_the_description_the_scene_and_the_plan_are_drawn(run):
    (desc,) = [m.ros_msg.data for m in read_ros2_messages(run, topics=["/robot_description"])]
    urdf = ET.fromstring(desc)
    links = {lk.get("name") for lk in urdf.findall("link")}
    model = load_robot("hsr")
    assert links == {j.child for j in model.urdf.joints if j.name not in BASE_JOINTS} | {"base_footprint"}
    assert not {j.get("name") for j in urdf.findall("joint")} & set(BASE_JOINTS)
    meshes = [m.get("filename", "") for m in urdf.iter("mesh")]
    assert all(Path(m.removeprefix("file://")).is_file() for m in meshes if m.startswith("file://"))
    scene = load_replay(run).scene
    with open(run, "rb") as f:
        updates = {}
        for _, ch, msg in make_reader(f).iter_messages(topics=["/scene_entities", "/plan_path"]):
            updates.setdefault(ch.topic, []).append(_entities(msg.data))
    first = updates["/scene_entities"][0]
    assert set(first) == ({f"fixture/{fx.name}" for fx in scene.fixtures} | {f"region/{r.name}" for r in scene.regions}
                          | {f"object/{o.name}" for o in scene.objects})
    assert bytes(first["object/block"][2][0]) == b"block" and first["object/block"][8]  # its own frame, a cube
    plan = updates["/plan_path"][-1]
    assert set(plan) == {"plan/base", *(f"plan/{m.name}" for m in model.config.manipulators)}
    assert all(e[11] for e in plan.values())  # line primitives


def test_a_sensed_scene_with_an_object_in_a_drawer_draws():
    """The executive records the world as sensed: a block dropped into the drawer (its pose from a ``make
    demo`` recording) keeps the file's random range, which a scene file may not have there; the viewer
    draws it all the same."""
    from rlgp_exec.executive.ros_record import RosView
    from rlgp_exec.scene.serialize import scene_to_dict
    from rlgp_exec.scene.shipped import shipped_scene

    data = scene_to_dict(shipped_scene("table_clearing_hsr"))
    block = next(o for o in data["object"] if o["name"] == "block")
    assert "random" in block
    block["pose"] = [1.1516, -0.1375, 0.365, -1.7103]  # in the drawer
    out = RosView().derive("/scene", data, 1.0)
    assert "/scene_entities" in {topic for topic, _ in out}
