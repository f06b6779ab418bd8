"""RobotModel: pinocchio FK == CasADi FK == PyBullet link poses, Jacobians, limits, collisions."""

from __future__ import annotations

import csv
import re
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pybullet as p
import pytest

from rlgp_exec.errors import ModelError
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.pybullet_body import PyBulletRobot
from rlgp_exec.robots import robot_dir

ROBOTS = ["hsr", "pr2"]
N_CONFIGS = 200


def rot_err(Ra: np.ndarray, Rb: np.ndarray) -> float:
    """Angle [rad] of Ra^T Rb."""
    c = np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)
    return float(np.arccos(c)) if c < 1.0 - 1e-15 else float(np.linalg.norm(Ra - Rb))


@pytest.fixture(scope="module", params=ROBOTS)
def robot(request):
    return load_robot(request.param)


@pytest.fixture(scope="module")
def body(robot):
    client = p.connect(p.DIRECT)
    yield PyBulletRobot(robot, client)
    p.disconnect(client)


def test_pinocchio_equals_casadi_fk(robot):
    frames = [m.tool_frame for m in robot.config.manipulators] + [robot.config.frames["camera"]]
    frames += sorted(robot.urdf.links_with_collision)
    fk = robot.casadi_fk(frames)
    rng = np.random.default_rng(1)
    for _ in range(N_CONFIGS):
        q = robot.random_q(rng)
        for T_pin, T_ca in zip(robot.fk_many(q, frames), fk(q), strict=True):
            T_ca = np.asarray(T_ca)
            assert np.abs(T_pin[:3, 3] - T_ca[:3, 3]).max() < 1e-6
            assert rot_err(T_pin[:3, :3], T_ca[:3, :3]) < 1e-6


def test_pinocchio_equals_pybullet_link_poses(robot, body):
    links = [name for name in body.link_index if name != "world"]
    rng = np.random.default_rng(2)
    for _ in range(N_CONFIGS):
        q = robot.random_q(rng)
        body.set_q(q)
        for link, T_pin in zip(links, robot.fk_many(q, links), strict=True):
            T_pb = body.link_pose(link)
            assert np.abs(T_pin[:3, 3] - T_pb[:3, 3]).max() < 1e-6, link
            assert rot_err(T_pin[:3, :3], T_pb[:3, :3]) < 1e-6, link


def test_get_q_round_trips_through_pybullet(robot, body):
    rng = np.random.default_rng(3)
    for _ in range(20):
        q = robot.limits.wrap(robot.random_q(rng))
        body.set_q(q)
        assert np.allclose(robot.limits.difference(body.get_q(), q), 0.0, atol=1e-9)


def _log_rot(R: np.ndarray) -> np.ndarray:
    import pinocchio as pin

    return np.asarray(pin.log3(R))


def test_frame_jacobians_match_finite_differences(robot):
    rng = np.random.default_rng(4)
    frames = [m.tool_frame for m in robot.config.manipulators] + [robot.config.frames["camera"]]
    eps = 1e-6
    for _ in range(20):
        q = robot.random_q(rng)
        for frame in frames:
            J = robot.jacobian(q, frame)
            T0 = robot.fk(q, frame)
            J_fd = np.zeros_like(J)
            for i in range(robot.nq):
                dq = np.zeros(robot.nq)
                dq[i] = eps
                Tp, Tm = robot.fk(q + dq, frame), robot.fk(q - dq, frame)
                J_fd[:3, i] = (Tp[:3, 3] - Tm[:3, 3]) / (2 * eps)
                # world-aligned angular velocity: log(R(q+dq) R(q)^T) / dq
                J_fd[3:, i] = (_log_rot(Tp[:3, :3] @ T0[:3, :3].T) - _log_rot(Tm[:3, :3] @ T0[:3, :3].T)) / (2 * eps)
            assert np.abs(J - J_fd).max() < 1e-5, frame


def test_home_pose_is_collision_free_and_within_limits(robot, body):
    q = robot.home()
    assert robot.limits.within(q)
    body.set_q(q)
    assert body.contacts() == []


def test_collision_query_sees_a_box_through_the_arm(robot, body):
    q = robot.home()
    body.set_q(q)
    tool = robot.fk(q, robot.manipulator().palm_frame)[:3, 3]
    shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.05, 0.05, 0.05], physicsClientId=body.client)
    box = p.createMultiBody(0, shape, basePosition=tool.tolist(), physicsClientId=body.client)
    try:
        hits = body.contacts()
        assert any(c.other_body == box for c in hits)
        body.ignore_body(box)
        assert not any(c.other_body == box for c in body.contacts())
    finally:
        body.ignore_body(box, False)
        p.removeBody(box, physicsClientId=body.client)
    assert body.contacts() == []


def test_self_collision_is_detected_when_the_arm_folds_into_the_body():
    robot = load_robot("hsr")
    client = p.connect(p.DIRECT)
    try:
        body = PyBulletRobot(robot, client)
        q = robot.home(joints={"arm_flex_joint": -2.6, "arm_lift_joint": 0.0, "wrist_flex_joint": 0.0,
                               "arm_roll_joint": 0.0})
        body.set_q(q)
        tool_z = robot.fk(q, "hand_tool_frame")[2, 3]
        assert tool_z < 0.31  # the hand is down inside the base cylinder
        assert any(c.is_self or c.other_body == body.id for c in body.contacts())
    finally:
        p.disconnect(client)


def test_the_hsr_wrist_folds_to_its_limit_without_touching_the_arm():
    """The real arm folds its wrist to -1.92 rad; our primitive arm link reached 7 mm into the wrist's
    and every keyframe that used the limit was refused as a self-collision (a block moved 2 cm made
    the shelf task unplannable)."""
    robot = load_robot("hsr")
    client = p.connect(p.DIRECT)
    try:
        body = PyBulletRobot(robot, client)
        a, b = body.link_index["arm_flex_link"], body.link_index["wrist_ft_sensor_mount_link"]
        rng = np.random.default_rng(0)
        lo, hi = robot.limits.lower, robot.limits.upper
        for _ in range(300):
            joints = {
                n: rng.uniform(lo[robot.index(n)], hi[robot.index(n)])
                for n in ("arm_flex_joint", "arm_roll_joint", "wrist_roll_joint")
            }
            joints["wrist_flex_joint"] = lo[robot.index("wrist_flex_joint")]
            body.set_q(robot.home(joints=joints))
            for c in p.getClosestPoints(body.id, body.id, 0.01, a, b, physicsClientId=client):
                assert c[8] > 0.0, (joints, c[8])
    finally:
        p.disconnect(client)


def test_limits_carry_continuous_joints_and_base_speeds():
    hsr, pr2 = load_robot("hsr"), load_robot("pr2")
    assert hsr.limits.names[:3] == ("base_x", "base_y", "base_yaw")
    assert list(hsr.limits.velocity[:3]) == [0.2, 0.2, 1.0]
    assert list(np.flatnonzero(hsr.limits.continuous)) == [2]
    cont = {pr2.limits.names[i] for i in np.flatnonzero(pr2.limits.continuous)}
    assert cont == {"base_yaw", "r_forearm_roll_joint", "r_wrist_roll_joint", "l_forearm_roll_joint",
                    "l_wrist_roll_joint"}
    assert pr2.nq == 3 + 1 + 7 + 7 + 2 + 2
    assert len(pr2.group("right_arm")) == 7 and len(pr2.group("left_arm")) == 7


def test_mimic_joints_follow_their_primary():
    hsr = load_robot("hsr")
    q = hsr.home(joints={"arm_lift_joint": 0.6})
    T_torso = hsr.fk(q, "torso_lift_link")
    assert T_torso[2, 3] == pytest.approx(0.752 + 0.3, abs=1e-12)
    client = p.connect(p.DIRECT)
    try:
        body = PyBulletRobot(hsr, client)
        body.set_q(q)
        assert body.link_pose("torso_lift_link")[2, 3] == pytest.approx(1.052, abs=1e-6)
    finally:
        p.disconnect(client)


@pytest.mark.parametrize(("lift", "height"), [(0.0, 1.005), (0.69, 1.35)])
def test_hsr_body_height_with_the_lift(lift, height):
    hsr = load_robot("hsr")
    client = p.connect(p.DIRECT)
    try:
        body = PyBulletRobot(hsr, client)
        body.set_q(hsr.home(joints={"arm_lift_joint": lift, "head_tilt_joint": 0.0, "arm_flex_joint": -1.57}))
        n_links = p.getNumJoints(body.id, physicsClientId=client)
        top = max(p.getAABB(body.id, i, physicsClientId=client)[1][2] for i in range(n_links))
        assert top == pytest.approx(height, abs=0.02)
        base_aabb = p.getAABB(body.id, body.link_index["base_link"], physicsClientId=client)
        assert base_aabb[1][0] - base_aabb[0][0] == pytest.approx(0.43, abs=0.008)  # AABBs carry a margin
    finally:
        p.disconnect(client)


def _numbers(text: str) -> list[float]:
    """The leading numbers of a kinematics-table cell ("0.141 0.078 0 (ROS2: 0.0785)" -> [0.141, 0.078, 0])."""
    head = text.split("(")[0]
    return [float(x) for x in re.findall(r"-?\d+(?:\.\d+)?", head)]


def test_hsr_urdf_matches_the_kinematics_table():
    folder = robot_dir("hsr")
    urdf = ET.parse(folder / "hsr.urdf").getroot()
    joints = {j.get("name"): j for j in urdf.findall("joint")}
    checked = 0
    with open(folder / "hsr_kinematics.csv") as f:
        for row in csv.DictReader(f):
            name = row["joint"]
            if name not in joints:
                continue
            j = joints[name]
            assert j.find("parent").get("link") == row["parent"], name
            if row["origin_xyz"]:
                xyz = [float(v) for v in j.find("origin").get("xyz").split()]
                assert np.allclose(xyz, _numbers(row["origin_xyz"])[:3]), name
            if row["axis"] and j.find("axis") is not None:
                axis = [float(v) for v in j.find("axis").get("xyz").split()]
                assert np.allclose(axis, _numbers(row["axis"])), name
            lim = j.find("limit")
            if row["lower"] and lim is not None:
                assert float(lim.get("lower")) == pytest.approx(_numbers(row["lower"])[0]), name
                assert float(lim.get("upper")) == pytest.approx(_numbers(row["upper"])[0]), name
                assert float(lim.get("velocity")) == pytest.approx(_numbers(row["vel_limit"])[0]), name
            checked += 1
    assert checked >= 12  # lift, torso, 5 arm, 2 head, hand motor, 2 fingers


def test_bad_names_and_shapes_raise_model_error_listing_the_options():
    hsr = load_robot("hsr")
    with pytest.raises(ModelError, match="valid"):
        hsr.index("elbow")
    with pytest.raises(ModelError, match="valid"):
        hsr.group("legs")
    with pytest.raises(ModelError, match=r"shape \(11,\)"):
        hsr.fk(np.zeros(5), "hand_tool_frame")
    with pytest.raises(ModelError, match="unknown frame"):
        hsr.fk(hsr.home(), "nose")
    with pytest.raises(ModelError, match="valid"):
        load_robot("nao")


def test_pr2_urdf_comes_from_the_wheel_with_package_paths_rewritten():
    pr2 = load_robot("pr2")
    text = Path(pr2.urdf.pybullet_path).read_text()
    assert "package://" not in text
    meshes = re.findall(r'filename="([^"]+)"', text)
    assert meshes and all(Path(m).is_file() for m in meshes)
    assert all("cmeel.prefix" in Path(m).parts for m in meshes)  # in the installed wheel, not copied here


def test_prepared_urdf_texts_are_kept_on_disk_by_what_they_are_made_from(tmp_path, monkeypatch):
    """The PyBullet, pinocchio and collision-only PyBullet texts are written once per set of inputs and read
    back equal; other base speeds (part of the prepended base joints) make other texts."""
    import dataclasses
    import tempfile

    from rlgp_exec.robot.config import load_robot_config
    from rlgp_exec.robot.urdf import prepare_urdf

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    cfg = load_robot_config("pr2")
    fresh = prepare_urdf(cfg)
    kept = sorted((tmp_path / "rlgp-exec-urdf").iterdir())
    assert len(kept) == 3 and sum(f.name.endswith(".pinocchio.urdf") for f in kept) == 1
    assert sum(f.name.endswith(".collision.urdf") for f in kept) == 1
    assert prepare_urdf(cfg) == fresh  # read back
    assert Path(fresh.pybullet_path).read_text().count('type="continuous"') > 0  # PyBullet's keeps them
    assert 'type="continuous"' not in fresh.pinocchio_xml
    slow = dataclasses.replace(cfg, base=dataclasses.replace(cfg.base, velocity=(0.1, 0.1, 0.1)))
    other = prepare_urdf(slow)
    assert other.pybullet_path != fresh.pybullet_path and other.pinocchio_xml != fresh.pinocchio_xml
    assert len(list((tmp_path / "rlgp-exec-urdf").iterdir())) == 6


def test_the_pr2_keyframe_wrist_limit_is_where_the_fingers_leave_the_forearm():
    """Random right-arm postures, left arm tucked: with the wrist flexed past ``keyframe_limits`` the open
    fingers are in the forearm's hull in most postures (beyond -1.9 rad: over 90 %), inside them about as
    rarely as anywhere (under 8 %); the keyframe NLP's bounds are the joint limits narrowed to them."""
    from rlgp_exec.planning.nlp.keyframes import _keyframe_bounds
    from rlgp_exec.reach import ReachIK
    from rlgp_exec.scene import load_scene

    robot = load_robot("pr2")
    lo_k, hi_k = robot.config.keyframe_limits["r_wrist_flex_joint"]
    client = p.connect(p.DIRECT)
    try:
        body = PyBulletRobot(robot, client)
        arm = np.array(robot.group("right_arm"))
        wrist = robot.index("r_wrist_flex_joint")
        forearm = body.link_index["r_forearm_link"]
        fingers = {body.link_index[n] for n in ("r_gripper_l_finger_link", "r_gripper_r_finger_link",
                                                "r_gripper_l_finger_tip_link", "r_gripper_r_finger_tip_link")}
        lo, hi = np.maximum(robot.limits.lower[arm], -3.0), np.minimum(robot.limits.upper[arm], 3.0)
        rng = np.random.default_rng(0)
        beyond, inside = [], []
        for _ in range(600):
            q = robot.home()
            q[arm] = rng.uniform(lo, hi)
            body.set_q(q)
            p.performCollisionDetection(physicsClientId=client)
            hit = any({c[3], c[4]} & {forearm} and {c[3], c[4]} & fingers and c[8] < -0.001
                      for c in p.getContactPoints(bodyA=body.id, bodyB=body.id, physicsClientId=client))
            if q[wrist] < -1.9:
                beyond.append(hit)
            elif lo_k <= q[wrist] <= hi_k:
                inside.append(hit)
        assert len(beyond) > 30 and np.mean(beyond) > 0.9
        assert len(inside) > 300 and np.mean(inside) < 0.08
    finally:
        p.disconnect(client)
    scene = load_scene(Path(__file__).resolve().parents[1] / "sim" / "scenes" / "pick_place_pr2.toml")
    ik = ReachIK(robot, scene, robot.home())
    lo_z, hi_z = _keyframe_bounds(robot, ik)
    k = int(np.flatnonzero(ik.idx == wrist)[0])
    assert (lo_z[k], hi_z[k]) == (max(ik.lo[k], lo_k), min(ik.hi[k], hi_k)) == (lo_k, 0.0)
    others = np.arange(len(ik.idx)) != k
    assert np.array_equal(lo_z[others], ik.lo[others]) and np.array_equal(hi_z[others], ik.hi[others])


@pytest.mark.parametrize(("entry", "match"), [
    ("no_such_joint = [-1.0, 0.0]", "keyframe_limits names 'no_such_joint', in no group; valid"),
    ("r_wrist_flex_joint = [0.0, -1.0]", "lower < upper"),
    ('r_wrist_flex_joint = "tight"', "must be \\[lower, upper\\]"),
])
def test_bad_keyframe_limits_are_model_errors_naming_the_entry(tmp_path, monkeypatch, entry, match):
    import rlgp_exec.robot.config as config

    text = (robot_dir("pr2") / "robot.toml").read_text()
    start = text.index("[keyframe_limits]")
    end = text.index("\n\n", start)
    (tmp_path / "robot.toml").write_text(text[:start] + "[keyframe_limits]\n" + entry + text[end:])
    monkeypatch.setattr(config, "robot_dir", lambda name: tmp_path)
    with pytest.raises(ModelError, match=match):
        config.load_robot_config("pr2")


def test_pairs_no_moving_joint_separates_are_left_out_with_the_same_verdicts():
    """``ignore_rigid_pairs``: for configurations that move the base and the right arm only, the pairs of
    links those joints do not move apart (the grippers' fingers, the tucked left arm's links, the
    casters) are no longer checked, and every penetration is the same as without the filter (random
    right-arm postures, many into the torso or the left arm); refused when such a pair already
    penetrates at the first configuration."""
    robot = load_robot("pr2")
    clients = [p.connect(p.DIRECT) for _ in range(2)]
    try:
        plain, filtered = (PyBulletRobot(robot, c) for c in clients)
        q0 = robot.home()
        arm = np.array([*robot.group("base"), *robot.group("right_arm")])
        rng = np.random.default_rng(4)
        lo, hi = np.maximum(robot.limits.lower[arm], -3.0), np.minimum(robot.limits.upper[arm], 3.0)
        qs = np.repeat(q0[None], 60, axis=0)
        qs[1:, arm] = rng.uniform(lo, hi, (59, arm.size))
        assert filtered.ignore_rigid_pairs(qs, tolerance=1e-3)
        plain.set_q(q0)
        assert any(c.is_self for c in plain.contacts(tolerance=-1e-3))  # the fingers touch each other...
        assert not any(c.is_self for c in filtered.contacts(tolerance=-1e-3))  # ...a pair left out
        hits = 0
        for q in qs[1:]:
            plain.set_q(q)
            filtered.set_q(q)
            a = {(c.link, c.other_link) for c in plain.contacts(tolerance=1e-3)}
            b = {(c.link, c.other_link) for c in filtered.contacts(tolerance=1e-3)}
            assert a == b
            hits += bool(a)
        assert hits > 10
        left = np.array(robot.group("left_arm"))  # a left-arm posture into the body, the left arm not moving
        lo_l, hi_l = np.maximum(robot.limits.lower[left], -3.0), np.minimum(robot.limits.upper[left], 3.0)
        for _ in range(200):
            into = q0.copy()
            into[left] = rng.uniform(lo_l, hi_l)
            plain.set_q(into)
            if any(c.is_self for c in plain.contacts(tolerance=1e-3)):
                break
        else:
            raise AssertionError("no left-arm posture into the body in 200 draws")
        fresh = PyBulletRobot(robot, clients[1])
        moves = np.repeat(into[None], 2, axis=0)
        moves[1, robot.group("right_arm")] += 0.1
        assert not fresh.ignore_rigid_pairs(moves, tolerance=1e-3)
        assert fresh.contacts(tolerance=1e-3)  # still checked
    finally:
        for c in clients:
            p.disconnect(c)


@pytest.mark.parametrize("name", ROBOTS)
def test_the_collision_only_body_collides_as_the_full_one(name):
    """The body of a collision-only world (``collision_only``: the links without collision shapes on fixed
    joints left out) reports the same self-contacts and the same distances to a box at random
    configurations as the full body; a left-out link rides on its ``carrier_index`` (a constant transform
    from it at every configuration)."""
    model = load_robot(name)
    assert model.urdf.pruned, "some links are left out"
    assert not set(model.urdf.pruned) & model.urdf.links_with_collision
    bodies, boxes = [], []
    for only in (False, True):
        client = p.connect(p.DIRECT)
        bodies.append(PyBulletRobot(model, client, collision_only=only))
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[0.3, 0.3, 0.4], physicsClientId=client)
        boxes.append(p.createMultiBody(0.0, col, -1, [0.6, 0.0, 0.6], physicsClientId=client))
    full, lean = bodies
    try:
        n_lean = p.getNumJoints(lean.id, physicsClientId=lean.client)
        assert n_lean < p.getNumJoints(full.id, physicsClientId=full.client)
        rng = np.random.default_rng(5)
        pruned = sorted(model.urdf.pruned)
        offsets = None
        for _ in range(N_CONFIGS):
            q = model.random_q(rng, base_box=0.3)
            seen = []
            for body, box in zip(bodies, boxes, strict=True):
                body.set_q(q)
                self_pairs = sorted((c.link, c.other_link, round(c.distance, 6)) for c in body.contacts(1e-3)
                                    if c.is_self)
                dist = sorted((body.link_name[c[3]], round(c[8], 6))
                              for c in p.getClosestPoints(body.id, box, 0.5, physicsClientId=body.client))
                seen.append((self_pairs, dist))
            assert seen[0] == seen[1]
            Ts = model.fk_many(q, pruned)
            carriers = model.fk_many(q, [lean.link_name[lean.carrier_index(n)] for n in pruned])
            rel = np.array([np.linalg.solve(C, T) for C, T in zip(carriers, Ts, strict=True)])
            if offsets is None:
                offsets = rel
            assert np.abs(rel - offsets).max() < 1e-9
    finally:
        for body in bodies:
            p.disconnect(body.client)
