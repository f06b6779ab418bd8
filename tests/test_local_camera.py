"""A local camera (rlgp_exec/perception/calibration.py, rlgp_exec/executive/local_camera.py): calibration files
in OpenCV's and ROS's formats, undistortion, and a video file feeding the camera object source."""

from __future__ import annotations

import itertools
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from rlgp_exec.errors import RlgpError
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.zenoh_keys import load_key_map
from rlgp_exec.perception.calibration import Undistorter, load_calibration
from rlgp_exec.perception.camera import PerceptionError, camera_for_robot
from rlgp_exec.scene import load_scene

SCENE = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "sorting_hsr.toml"
K = np.array([[577.3, 0.0, 319.5], [0.0, 577.3, 239.5], [0.0, 0.0, 1.0]])
D = np.array([-0.12, 0.03, 0.0, 0.0, 0.0])
THREE_D = "distortion_coefficients: {rows: 1, cols: 3, data: [0.1, 0.2, 0.3]}"
GOOD_K = "camera_matrix: {rows: 3, cols: 3, data: [500, 0, 320, 0, 500, 240, 0, 0, 1]}"


def _opencv_file(path: Path, K: np.ndarray = K, D: np.ndarray = D, w: int = 640, h: int = 480) -> Path:
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", w)
    fs.write("image_height", h)
    fs.write("camera_matrix", K)
    fs.write("distortion_coefficients", D.reshape(1, -1))
    fs.release()
    return path


def _ros_file(path: Path) -> Path:
    path.write_text(
        "image_width: 640\nimage_height: 480\ncamera_name: head\n"
        f"camera_matrix:\n  rows: 3\n  cols: 3\n  data: {K.reshape(-1).tolist()}\n"
        f"distortion_model: plumb_bob\ndistortion_coefficients:\n  rows: 1\n  cols: 5\n  data: {D.tolist()}\n"
    )
    return path


def test_opencv_and_ros_calibration_files_read_the_same(tmp_path):
    a = load_calibration(_opencv_file(tmp_path / "cv.yaml"))
    b = load_calibration(_ros_file(tmp_path / "ros.yaml"))
    for c in (a, b):
        assert (c.width, c.height) == (640, 480)
        assert np.allclose(c.K, K) and np.allclose(c.dist, D)


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("image_width: 640\nimage_height: 480\n", "missing camera_matrix"),
        ("image_width: 640\ncamera_matrix: {rows: 3, cols: 3, data: [1, 0, 1, 0, 1, 1, 0, 0, 1]}\n", "image_height"),
        ("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 2, cols: 2, data: [1, 0, 0, 1]}\n", "3 x 3"),
        ("image_width: 640\nimage_height: 480\ncamera_matrix: {rows: 3, cols: 3, data: [0, 0, 0, 0, 0, 0, 0, 0, 0]}\n",
         "not a pinhole"),
        (f"image_width: 640\nimage_height: 480\n{GOOD_K}\n{THREE_D}\n", "distortion_coefficients"),
        (f"image_width: 5\nimage_height: 480\n{GOOD_K}\n", "16 to 8192"),
        ("not: [a calibration", "calibration"),
    ],
)
def test_a_bad_calibration_file_is_refused_by_what_is_wrong(tmp_path, text, says):
    path = tmp_path / "cal.yaml"
    path.write_text(text)
    with pytest.raises(PerceptionError, match=says):
        load_calibration(path)


def test_a_missing_calibration_file_is_named(tmp_path):
    with pytest.raises(PerceptionError, match="does not exist"):
        load_calibration(tmp_path / "none.yaml")


def test_undistortion_puts_a_point_where_the_pinhole_model_of_the_new_matrix_projects_it(tmp_path):
    u = Undistorter(load_calibration(_opencv_file(tmp_path / "cv.yaml")))
    p_cam = np.array([[0.45, -0.33, 1.0]])  # near a corner, where the distortion is large
    seen, _ = cv2.projectPoints(p_cam, np.zeros(3), np.zeros(3), K, D)  # where the lens puts it
    img = np.zeros((480, 640), np.uint8)
    cv2.circle(img, tuple(round(float(v)) for v in seen.reshape(2)), 3, 255, -1)
    out = u(img)
    ys, xs = np.nonzero(out > 127)
    ideal = u.intrinsics.project(p_cam)[0]
    assert abs(xs.mean() - ideal[0]) < 1.0 and abs(ys.mean() - ideal[1]) < 1.0
    pinhole = (K @ p_cam[0])[:2] / p_cam[0, 2]  # the calibrated matrix without the lens model
    assert np.linalg.norm(seen.reshape(2) - pinhole) > 5.0  # what PnP would be off by undistorted
    with pytest.raises(PerceptionError, match="calibration is for 640x480"):
        u(np.zeros((240, 320), np.uint8))


def test_a_video_file_feeds_the_camera_source_which_places_the_tags(tmp_path):
    """Rendered head-camera frames as a video file with a calibration file: the local camera stamps them
    with the robot's clock and the source places the block through FK, as from the robot's topics."""
    from rlgp_exec.executive.camera_source import CameraObjects
    from rlgp_exec.executive.local_camera import LocalCamera
    from rlgp_exec.perception.rendered_camera import hide_floor, render_camera
    from rlgp_exec.world.pybullet_world import build_world

    scene = load_scene(SCENE)
    world = build_world(scene)
    cam = camera_for_robot("hsr")
    try:
        img = render_camera(world, cam, background=hide_floor(world))
        truth = world.object_pose("block_blue")
        q = world.robot.get_q()
        model = world.robot_model
    finally:
        world.close()
    video = tmp_path / "head.avi"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (cam.width, cam.height))
    assert out.isOpened()
    for _ in range(12):
        out.write(cv2.cvtColor(img, cv2.COLOR_RGB2BGR))
    out.release()
    cal = _opencv_file(tmp_path / "cam.yaml", cam.K, np.zeros(5), cam.width, cam.height)

    src = CameraObjects(None, load_key_map("hsr"), model, scene, images=False)
    names = tuple(model.joint_names[3:])
    stop = threading.Event()

    def robot() -> None:  # the robot's joint states, 100 Hz on its own clock
        t = 0.0
        while not stop.is_set():
            src.history.on_joint_states(rc.encode_joint_state(t, names, q[3:], np.zeros(len(names))))
            src.history.on_odom(rc.encode_odometry(t, *q[:3], 0.0, 0.0, 0.0))
            t += 0.01
            time.sleep(0.01)

    feeder = threading.Thread(target=robot, daemon=True)
    feeder.start()
    try:
        time.sleep(0.1)
        local = LocalCamera(str(video), cal, src)
        src.feeds.append(local.start())
        assert local.ended.wait(20.0)
        time.sleep(0.3)
        est = src.perception.tracker.estimate("block_blue")
        assert local.frames >= 10 and src.frames >= 2
        assert est is not None and est.n_updates >= 2
        assert float(np.linalg.norm(est.T_world_object[:3, 3] - truth[:3, 3])) < 0.01  # through a JPEG video
    finally:
        stop.set()
        src.close()


def test_a_local_camera_that_is_not_there_is_named(tmp_path):
    from rlgp_exec.executive.local_camera import open_capture

    with pytest.raises(RlgpError, match="no such device or video file"):
        open_capture(str(tmp_path / "none.avi"))


def test_camera_and_calibration_go_together():
    from rlgp_exec.executive.runner import RunOptions, object_source_name

    with pytest.raises(RlgpError, match="go together"):
        object_source_name(RunOptions(backend="zenoh", camera="/dev/video0"))
    with pytest.raises(RlgpError, match="needs --objects camera"):
        object_source_name(RunOptions(backend="zenoh", objects="mocap", camera="0", calibration=Path("c.yaml")))


def test_a_local_cameras_frames_are_recorded_on_the_head_cameras_topics(tmp_path):
    """``run --camera VIDEO --calibration FILE`` with a recording: the frames the local camera reads are
    recorded (thinned) as JPEG CompressedImage and the calibration's CameraInfo on the robot's head camera
    topics, and read back by the ROS 2 reader."""
    from contextlib import ExitStack
    from types import SimpleNamespace

    from mcap_ros2.reader import read_ros2_messages

    from rlgp_exec.executive.camera_record import camera_topics
    from rlgp_exec.executive.camera_source import CameraObjects
    from rlgp_exec.executive.local_camera import LocalCamera
    from rlgp_exec.executive.recorder import Recorder
    from rlgp_exec.executive.runner import RunOptions, record_camera
    from rlgp_exec.robot import load_robot

    scene, model, keys = load_scene(SCENE), load_robot("hsr"), load_key_map("hsr")
    rng = np.random.default_rng(5)
    video = tmp_path / "lab.avi"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (640, 480))
    assert out.isOpened()
    for _ in range(30):  # 2 s at the camera's 15 Hz
        out.write(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8))
    out.release()
    cal = _opencv_file(tmp_path / "cam.yaml")
    src = CameraObjects(None, keys, model, scene, images=False)
    names = tuple(model.joint_names[3:])
    q = model.home(scene.robot.base)
    src.history.on_joint_states(rc.encode_joint_state(1.0, names, q[3:], np.zeros(len(names))))
    path = tmp_path / "run.mcap"
    opts = RunOptions(backend="zenoh", objects="camera", camera=str(video), calibration=cal, camera_record_hz=4.0)
    local = LocalCamera(str(video), cal, src)
    src.feeds.append(local)
    try:
        with Recorder(path) as rec, ExitStack() as stack:
            record_camera(stack, rec, SimpleNamespace(keys=keys, session=None), src, opts)
            assert local.on_frame is not None
            local.start()
            assert local.ended.wait(20.0)
        assert local.on_frame is None  # unset at the run's end, before the recording closes
    finally:
        src.close()
    image_topic, info_topic = camera_topics(keys)
    msgs = list(read_ros2_messages(str(path), topics=[image_topic, info_topic]))
    images = [m.ros_msg for m in msgs if m.channel.topic == image_topic]
    infos = [m.ros_msg for m in msgs if m.channel.topic == info_topic]
    assert 5 <= len(images) == len(infos) <= 10, len(images)  # 2 s of video at 4 Hz
    c = local.undistort.intrinsics
    for img, info in zip(images, infos, strict=True):
        assert img.header.frame_id == info.header.frame_id == model.config.frames["camera"]
        assert (img.header.stamp.sec, img.header.stamp.nanosec) == (info.header.stamp.sec, info.header.stamp.nanosec)
        assert "jpeg" in img.format
        rgb = cv2.imdecode(np.frombuffer(bytes(img.data), np.uint8), cv2.IMREAD_COLOR)
        assert rgb.shape == (c.height, c.width, 3) and (info.width, info.height) == (c.width, c.height)
        assert np.allclose(np.array(info.k).reshape(3, 3), c.K)
    stamps = [i.header.stamp.sec + i.header.stamp.nanosec * 1e-9 for i in images]
    assert all(b - a >= 0.25 - 1e-6 for a, b in itertools.pairwise(stamps))
    assert abs(stamps[-1] - time.time()) < 60  # the recording's (wall) clock


def test_the_daemons_task_recordings_hold_a_local_cameras_frames(tmp_path):
    """The daemon with a local camera: each task's MCAP holds the frames read while the task ran, on the
    head camera's topics, and the camera stops feeding the recording when the task ends."""
    from types import SimpleNamespace

    from mcap_ros2.reader import read_ros2_messages

    from rlgp_exec.executive.camera_record import camera_topics
    from rlgp_exec.executive.camera_source import CameraObjects
    from rlgp_exec.executive.daemon import Daemon, DaemonOptions, _Task
    from rlgp_exec.executive.local_camera import LocalCamera
    from rlgp_exec.executive.runner import RunOptions
    from rlgp_exec.robot import load_robot

    scene, model, keys = load_scene(SCENE), load_robot("hsr"), load_key_map("hsr")
    rng = np.random.default_rng(6)
    video = tmp_path / "lab.avi"
    out = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"MJPG"), 15.0, (640, 480))
    for _ in range(30):
        out.write(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8))
    out.release()
    cal = _opencv_file(tmp_path / "cam.yaml")
    src = CameraObjects(None, keys, model, scene, images=False)
    names = tuple(model.joint_names[3:])
    src.history.on_joint_states(rc.encode_joint_state(1.0, names, model.home(scene.robot.base)[3:],
                                                      np.zeros(len(names))))
    local = LocalCamera(str(video), cal, src)
    src.feeds.append(local)
    opts = RunOptions(backend="zenoh", objects="camera", camera=str(video), calibration=cal, camera_record_hz=4.0)
    daemon = Daemon(scene, opts, DaemonOptions(record_dir=tmp_path / "tasks"))
    (tmp_path / "tasks").mkdir()
    daemon._hal, daemon._objects = SimpleNamespace(keys=keys, session=None), src

    class TaskThatWatches:  # the executive's part: the task runs while the camera reads the video
        def attach(self, rec):
            self.rec = rec

        def run(self, literals):
            assert local.on_frame is not None and self.rec is not None
            local.start()
            assert local.ended.wait(20.0)
            return "done"

    daemon.executive = TaskThatWatches()  # type: ignore[assignment]
    try:
        assert daemon._run(_Task(1, ("(on block tray)",))) == "done"
        assert local.on_frame is None and daemon.executive.rec is None
    finally:
        src.close()
    (path,) = (tmp_path / "tasks").glob("task0001-*.mcap")
    image_topic, _ = camera_topics(keys)
    images = [m for m in read_ros2_messages(str(path), topics=[image_topic])]
    assert 5 <= len(images) <= 10, len(images)  # 2 s of video at 4 Hz
