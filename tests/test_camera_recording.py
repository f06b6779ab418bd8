"""The head camera's images in recordings: a real run with the camera in the loop over Zenoh, read back
with the ROS 2 reader; and bad camera payloads counted, never raised."""

from __future__ import annotations

import threading
import time
from pathlib import Path
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from mcap_ros2.reader import read_ros2_messages

from rlgp_exec.executive.camera_record import COMPRESSED, CameraTap, camera_topics
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal import ros_image as ri
from rlgp_exec.hal.ros_codec import Rejected
from rlgp_exec.hal.zenoh_keys import load_key_map
from rlgp_exec.perception.camera import camera_for_robot
from rlgp_exec.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "sim" / "scenes" / "sorting_hsr.toml"
RATE_HZ = 4.0


class _Sink:
    """A record sink keeping what it is given."""

    def __init__(self) -> None:
        self.on_error = None
        self.records: list[tuple[str, dict]] = []
        self.ros: list[tuple[str, str, bytes, float]] = []

    def write(self, topic, data, t_wall=None):
        self.records.append((topic, data))

    def write_ros(self, topic, typename, payload, t_wall):
        self.ros.append((topic, typename, payload, t_wall))


class _Session:
    """A Zenoh session's subscriber side: the test calls the callbacks."""

    def __init__(self) -> None:
        self.callbacks: dict[str, object] = {}

    def declare_subscriber(self, key, cb):
        self.callbacks[key] = cb
        return self

    def undeclare(self) -> None:
        pass


def _sample(key: str, payload: bytes) -> SimpleNamespace:
    return SimpleNamespace(key_expr=key, payload=SimpleNamespace(to_bytes=lambda: payload))


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    """sim-robot with its camera node; the executive senses by camera, records, and is cancelled 4 s into
    its first motion."""
    from rlgp_exec.executive import Executive, Recorder
    from rlgp_exec.executive.runner import RunOptions, connect
    from rlgp_exec.sim.robot_process import RobotProcess

    path = tmp_path_factory.mktemp("camera") / "run.mcap"
    scene = load_scene(SCENE)
    with RobotProcess(SCENE, camera=True) as robot:
        hal, objects = connect(scene, RunOptions(backend="zenoh", endpoint=robot.endpoint, heartbeat_timeout_s=1.0))
        try:
            with Recorder(path) as rec:
                t0 = time.monotonic()  # the tap's life: the frames it may record
                tap = CameraTap(rec, hal.session, hal.keys, RATE_HZ)
                try:
                    ex = Executive(hal, scene, objects, recorder=rec)
                    timer, moving = threading.Timer(4.0, ex.cancel), threading.Event()

                    def on_phase(k: int, n: int) -> None:
                        if not moving.is_set():
                            moving.set()
                            timer.start()

                    ex.actor.on_phase = on_phase
                    result = ex.run()
                    timer.cancel()
                finally:
                    tap.close()
                    elapsed = time.monotonic() - t0
        finally:
            objects.close()
            hal.shutdown()
    assert moving.is_set() and result.status.value == "cancelled", result  # cancelled in motion
    return path, tap.stats(), elapsed


def test_the_recording_has_the_cameras_images_thinned_and_stamped(run):
    path, stats, elapsed = run
    image_topic, info_topic = camera_topics(load_key_map("hsr"))
    assert image_topic == "/hsrb/head_rgbd_sensor/rgb/image_rect_color/compressed"
    images, infos, tf_stamps = [], [], []
    for m in read_ros2_messages(path, topics=[image_topic, info_topic, "/tf"]):
        st = m.ros_msg.header.stamp if m.channel.topic != "/tf" else m.ros_msg.transforms[0].header.stamp
        stamp = st.sec + st.nanosec * 1e-9
        if m.channel.topic == image_topic:
            assert m.schema.name == "sensor_msgs/msg/CompressedImage" and "jpeg" in m.ros_msg.format
            img = cv2.imdecode(np.frombuffer(bytes(m.ros_msg.data), np.uint8), cv2.IMREAD_COLOR)
            assert img is not None and img.shape == (480, 640, 3)
            images.append((stamp, m.log_time_ns * 1e-9, m.ros_msg.header.frame_id))
        elif m.channel.topic == info_topic:
            infos.append((stamp, m.ros_msg))
        else:
            tf_stamps.append(stamp)
    assert len(images) >= 3, stats
    assert len(infos) == len(images)
    stamps = np.array([s for s, _, _ in images])
    # each a frame taken at least a period after the last (robot clock; the mapping onto the recording's
    # clock moves a stamp by the spread of the robot states' transport delay: a few ms)
    assert np.all(np.diff(stamps) > 1.0 / RATE_HZ - 0.02)
    assert len(images) <= elapsed * RATE_HZ + 1
    # on the recording's clock, taken before it was logged, within the TF's span
    assert all(s <= t for s, t, _ in images)
    assert min(tf_stamps) - 1.0 <= stamps[0] and stamps[-1] <= max(tf_stamps) + 1.0
    cam = camera_for_robot("hsr")
    for (s_img, _, frame), (s_info, info) in zip(images, infos, strict=True):
        assert s_info == s_img and info.header.frame_id == frame != ""
        assert (info.width, info.height) == (640, 480)
        np.testing.assert_allclose(np.asarray(info.k).reshape(3, 3), cam.K)
    assert stats["written"] == len(images) and stats["rejected"] == {}
    assert stats["received"] > stats["written"] and stats["thinned"] > 0


def test_replay_reads_a_recording_with_images(run):
    from rlgp_exec.executive import read_recording
    from rlgp_exec.executive.replay import load_replay

    path, stats, _ = run
    image_topic, info_topic = camera_topics(load_key_map("hsr"))
    rec = read_recording(path)
    assert rec.complete and rec.derived[image_topic] == rec.derived[info_topic] == stats["written"]
    assert all(topic not in (image_topic, info_topic) for topic, _, _ in rec.messages)
    assert load_replay(path).states  # the robot's motion, as replay plays it


def test_a_cut_recording_with_images_reads_its_prefix(run, tmp_path):
    from rlgp_exec.executive import read_recording

    path, _, _ = run
    data = path.read_bytes()
    image_topic, _ = camera_topics(load_key_map("hsr"))
    full = read_recording(path).derived[image_topic]
    cut = tmp_path / "cut.mcap"
    for frac in np.linspace(0.05, 0.99, 23):  # cuts through image records among the others
        cut.write_bytes(data[: int(len(data) * frac)])
        rec = read_recording(cut)
        assert not rec.complete and rec.derived.get(image_topic, 0) <= full


def test_bad_camera_payloads_are_counted_not_raised():
    keys = load_key_map("hsr")
    cam = camera_for_robot("hsr")
    sink, session = _Sink(), _Session()
    tap = CameraTap(sink, session, keys, rate_hz=10.0)
    image_key, info_key = keys["camera_image"].key, keys["camera_info"].key

    def put(key: str, payload: bytes) -> None:
        session.callbacks[key](_sample(key, payload))  # type: ignore[operator]

    def settle() -> None:
        end = time.monotonic() + 5.0
        while time.monotonic() < end:
            with tap._cond:
                if tap._slot is None:
                    break
            time.sleep(0.01)
        time.sleep(0.1)  # the worker's frame in hand

    rgb = np.zeros((480, 640, 3), np.uint8)
    try:
        put(keys["joint_states"].key, rc.encode_joint_state(1.0, ["head_pan_joint"], [0.0], [0.0]))
        put(image_key, ri.encode_image(1.0, "cam", rgb))  # before any CameraInfo
        settle()
        put(info_key, b"\x00\x01\x00\x00garbage")
        put(info_key, ri.encode_camera_info(1.0, "cam", 640, 480, np.zeros((3, 3))))
        put(info_key, ri.encode_camera_info(1.0, "cam", cam.width, cam.height, cam.K))
        for bad in [b"", b"\x00\x01\x00\x00" + b"\xff" * 40, b"not cdr at all",
                    ri.encode_image(2.0, "cam", np.zeros((8, 8, 3), np.uint8))]:  # too small a camera
            put(image_key, bad)
            settle()
        put(image_key, ri.encode_image(5.0, "cam", np.zeros((240, 320, 3), np.uint8)))  # not the CameraInfo's size
        settle()
        put(image_key, ri.encode_image(6.0, "cam", rgb))
        settle()
    finally:
        tap.close()
    counts = tap.stats()["rejected"]
    assert counts.get("no_camera_info") == 1 and counts.get("inconsistent") == 1
    assert counts.get("malformed", 0) + counts.get("singular", 0) >= 2  # the two bad CameraInfos
    assert sum(counts.values()) >= 7, counts
    assert [t for _, t, _, _ in sink.ros] == ["sensor_msgs/msg/CameraInfo", "sensor_msgs/msg/CompressedImage"]
    frame = ri.parse_compressed(sink.ros[1][2])
    assert not isinstance(frame, Rejected)
    assert frame.size == (640, 480)
    assert frame.stamp == pytest.approx(6.0 + tap._offset(), abs=1e-6) and tap._offset() > 1e9  # the wall's clock


def test_frames_arriving_while_one_is_written_replace_each_other_and_are_counted():
    """The camera's callback never waits on the worker: while a write is held up, the newest frame
    waits in the slot, the ones it replaced are counted as dropped, and a frame within the period is
    thinned."""
    keys = load_key_map("hsr")
    cam = camera_for_robot("hsr")
    release = threading.Event()

    class _SlowSink(_Sink):
        def write_ros(self, topic, typename, payload, t_wall):
            release.wait(10.0)
            super().write_ros(topic, typename, payload, t_wall)

    sink, session = _SlowSink(), _Session()
    tap = CameraTap(sink, session, keys, rate_hz=2.0)

    def put(key: str, payload: bytes) -> None:
        session.callbacks[key](_sample(key, payload))  # type: ignore[operator]

    rgb = np.zeros((cam.height, cam.width, 3), np.uint8)
    try:
        put(keys["joint_states"].key, rc.encode_joint_state(0.0, ["head_pan_joint"], [0.0], [0.0]))
        put(keys["camera_info"].key, ri.encode_camera_info(0.0, "cam", cam.width, cam.height, cam.K))
        put(keys["camera_image"].key, ri.encode_image(1.0, "cam", rgb))
        end = time.monotonic() + 10.0
        while tap._last_kept != 1.0 and time.monotonic() < end:  # the worker holds frame 1.0 in its write
            time.sleep(0.01)
        for stamp in (1.2, 2.0, 3.0, 4.0):  # 1.2: within 0.5 s of 1.0; the others replace each other
            put(keys["camera_image"].key, ri.encode_image(stamp, "cam", rgb))
        assert tap.stats()["dropped"] == 2 and tap.stats()["thinned"] == 1 and not sink.ros
        release.set()
        while tap.stats()["written"] < 2 and time.monotonic() < end:
            time.sleep(0.01)
    finally:
        release.set()
        tap.close()
    stamps = [ri.parse_compressed(p).stamp - tap._offset() for _, t, p, _ in sink.ros if t == COMPRESSED]
    assert stamps == pytest.approx([1.0, 4.0], abs=1e-6)
    assert tap.stats() == {"received": 5, "thinned": 1, "dropped": 2, "written": 2, "rejected": {}}


def _png_compressed(stamp: float, frame_id: str, rgb: np.ndarray) -> bytes:
    """sensor_msgs/CompressedImage, PNG (a robot's ``.../compressed`` topic with png_level set)."""
    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    assert ok
    msg = rc._t(COMPRESSED)(header=rc._header(stamp, frame_id), format="rgb8; png compressed bgr8",
                            data=np.asarray(buf, np.uint8).reshape(-1))
    return rc._ser(msg, COMPRESSED)


def test_a_robot_publishing_only_compressed_images_is_recorded_as_it_publishes(tmp_path):
    """JPEG and PNG frames from ``.../image_rect_color/compressed`` reach the recording with their bytes
    and format untouched (no re-encoding), restamped onto the recording's clock and read back by the
    ROS 2 reader; a raw Image arriving afterwards is left (the first kind wins) and counted."""
    from rlgp_exec.executive.recorder import Recorder

    keys = load_key_map("hsr")
    cam = camera_for_robot("hsr")
    rng = np.random.default_rng(3)
    rgb = rng.integers(0, 255, (cam.height, cam.width, 3), dtype=np.uint8)
    sent = {1.0: ri.encode_compressed(1.0, "cam", rgb, quality=70), 2.0: _png_compressed(2.0, "cam", rgb)}
    session, path = _Session(), tmp_path / "compressed.mcap"
    with Recorder(path) as rec:
        tap = CameraTap(rec, session, keys, rate_hz=10.0)

        def put(key: str, payload: bytes) -> None:
            session.callbacks[key](_sample(key, payload))  # type: ignore[operator]

        try:
            put(keys["joint_states"].key, rc.encode_joint_state(1.0, ["head_pan_joint"], [0.0], [0.0]))
            put(keys["camera_info"].key, ri.encode_camera_info(1.0, "cam", cam.width, cam.height, cam.K))
            for stamp, payload in sent.items():
                put(keys["camera_compressed"].key, payload)
                end = time.monotonic() + 10.0
                while tap.stats()["written"] < len([s for s in sent if s <= stamp]) and time.monotonic() < end:
                    time.sleep(0.01)
            put(keys["camera_image"].key, ri.encode_image(3.0, "cam", rgb))
            time.sleep(0.2)
            offset = tap._offset()
        finally:
            tap.close()
    stats = tap.stats()
    assert stats["written"] == 2 and stats["other_kind"] == 1 and stats["rejected"] == {}, stats
    image_topic, _ = camera_topics(keys)
    got = [m.ros_msg for m in read_ros2_messages(str(path), topics=[image_topic])]
    assert len(got) == 2
    for m, (stamp, payload) in zip(got, sent.items(), strict=True):
        original = rc.decode(payload, COMPRESSED, ri.MAX_IMAGE_BYTES)
        assert m.format == original.format and bytes(m.data) == bytes(original.data)  # not re-encoded
        assert m.header.stamp.sec + m.header.stamp.nanosec * 1e-9 == pytest.approx(stamp + offset, abs=1e-6)
    assert "png" in got[1].format
    decoded = cv2.imdecode(np.frombuffer(bytes(got[1].data), np.uint8), cv2.IMREAD_COLOR)
    assert np.array_equal(decoded[:, :, ::-1], rgb)  # PNG: the robot's pixels exactly
