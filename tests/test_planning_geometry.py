"""Keyframe NLP (level 2), guided paths and replay validation for candidate action sequences."""

from __future__ import annotations

import itertools
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.keyframes import solve_keyframes
from rlgp_exec.planning.validate import Phase, validate_plan, validate_with_fallbacks
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene

SORTING = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "sorting_hsr.toml"
SEQUENCE = [
    Action("pick", "block_blue"),
    Action("place", "block_blue", "tray_blue"),
    Action("pick", "block_green"),
    Action("place", "block_green", "tray_green"),
]


@pytest.fixture(scope="module")
def scene():
    return load_scene(SORTING)


def test_keyframes_grasp_from_above_and_place_inside_the_region(scene):
    model = load_robot("hsr")
    q0 = model.home(scene.robot.base, scene.robot.joints)
    res = solve_keyframes(model, scene, q0, SEQUENCE)
    assert res.ok, res.reason
    tool = model.manipulator().tool_frame
    for k, a in enumerate(SEQUENCE):
        T = model.fk(res.keyframes[k], tool)
        approach = T[:3, :3] @ np.asarray(model.manipulator().approach)
        if a.name == "pick":
            assert approach[2] <= -np.cos(0.6) + 1e-6  # from above, tilted at most 0.6 rad
        before = res.object_poses[k - 1] if k else {o.name: o.T for o in scene.objects}
        if a.name == "pick":
            o = scene.object(a.obj)
            top = before[a.obj][:3, 3] + [0, 0, o.size[2] / 2 - 0.025]
            assert np.linalg.norm(T[:3, 3] - top) < 1e-3
        else:
            # the held object moved with the hand, and now rests upright inside the region
            T_obj = res.object_poses[k][a.obj]
            region = next(r for r in scene.regions if r.name == a.target)
            fx = scene.fixture(region.on)
            local = np.linalg.inv(fx.T) @ T_obj[:, 3]
            assert (
                abs(local[0] - region.offset[0]) <= region.size[0] / 2
                and abs(local[1] - region.offset[1]) <= region.size[1] / 2
            )
            assert T_obj[2, 2] >= 0.999 - 1e-6
            assert abs(T_obj[2, 3] - scene.object(a.obj).size[2] / 2 - (fx.pose[2] + fx.size[2] / 2)) < 0.006


def test_bad_sequences_are_errors_naming_the_action(scene):
    model = load_robot("hsr")
    q0 = model.home(scene.robot.base, scene.robot.joints)
    with pytest.raises(RlgpError, match="without holding"):
        solve_keyframes(model, scene, q0, [Action("place", "block_blue", "tray_blue")])
    with pytest.raises(RlgpError, match="unknown object"):
        solve_keyframes(model, scene, q0, [Action("pick", "unicorn")])
    with pytest.raises(RlgpError, match="not a region or fixture"):
        solve_keyframes(model, scene, q0, [Action("pick", "block_blue"), Action("place", "block_blue", "moon")])


def test_rlgp_finds_a_validated_plan_whose_phases_meet(scene):
    from rlgp_exec.planning.rlgp import plan_scene

    plan = plan_scene(scene, "rlgp")
    assert plan.success, plan.reason
    assert plan.validation is not None and plan.validation.collision_free and plan.validation.goal_met
    assert sorted(plan.actions) == sorted(str(a) for a in SEQUENCE) and len(plan.actions) == 4
    picks = [a.split()[1].rstrip(")") for a in plan.actions if a.startswith("(pick")]
    # per action: a guided path down to the keyframe, then straight up again
    assert [p.grasp for p in plan.phases] == [picks[0], None, None, None, picks[1], None, None, None]
    assert [p.release for p in plan.phases] == [None, None, picks[0], None, None, None, picks[1], None]
    assert [p.held for p in plan.phases] == [None, picks[0], picks[0], None, None, picks[1], picks[1], None]
    for k, ph in enumerate(plan.phases):
        if k % 2 == 0:
            assert np.allclose(ph.path[-1], plan.keyframes[k // 2])  # the keyframes are reached exactly
        if k:
            assert np.allclose(ph.path[0], plan.phases[k - 1].path[-1])  # phases meet
    assert plan.summary()["n_steps"] == 4 and plan.base_path_length_m > 1.0


def test_the_replay_catches_collisions_and_unmet_goals(scene):
    model = load_robot("hsr")
    q0 = model.home(scene.robot.base, scene.robot.joints)
    through_table = q0.copy()
    through_table[1] = 0.0  # drive the base into the middle table
    v = validate_plan(scene, [Phase(np.array([q0, through_table]), None)])
    assert not v.collision_free and any("table_mid" in c for c in v.collisions)
    standing = validate_plan(scene, [Phase(np.array([q0, q0]), None)])
    assert standing.collision_free and not standing.goal_met and len(standing.unmet) == 2


def test_a_fallback_is_replayed_in_place_as_a_whole_replay_with_it_would(scene, monkeypatch):
    """``validate_with_fallbacks`` replays a colliding phase again on its fallback, from where the phase
    started, and goes on (one world, one pass): the same validation as replaying the plan with the
    fallback in place; a fallback that collides too ends the replay there."""
    from rlgp_exec.world import pybullet_world

    worlds = []
    build = pybullet_world.build_world
    monkeypatch.setattr(pybullet_world, "build_world", lambda *a, **k: worlds.append(1) or build(*a, **k))
    model = load_robot("hsr")
    q0 = model.home(scene.robot.base, scene.robot.joints)
    aside = q0.copy()
    aside[0] += 0.3  # along the table's side
    through_table = q0.copy()
    through_table[1] = 0.0  # into the middle table
    there = Phase(np.array([q0, through_table, aside]), None)
    around = Phase(np.array([q0, aside]), None)
    back = Phase(np.array([aside, q0]), None)
    v, out, kept = validate_with_fallbacks(scene, [there, back], {0: around})
    assert len(worlds) == 1
    whole = validate_plan(scene, [around, back])
    assert out == [around, back] and kept == set()
    assert v.collision_free and whole.collision_free and v.unmet == whole.unmet
    assert all(np.allclose(v.final_poses[o], whole.final_poses[o]) for o in whole.final_poses)
    kept_there = validate_with_fallbacks(scene, [around, back], {0: there})  # no collision: kept
    assert kept_there[1] == [around, back] and kept_there[2] == {0}
    also_through = Phase(np.array([q0, through_table, through_table, aside]), None)
    v2, out2, kept2 = validate_with_fallbacks(scene, [there, back], {0: also_through})
    assert not v2.collision_free and v2.collisions[0].startswith("phase 0:") and kept2 == set()
    assert out2 == [also_through, back]
    with pytest.raises(ValueError, match="drives a drawer"):
        validate_with_fallbacks(scene, [Phase(there.path, None, knob="x", drives_drawer=True)], {0: around})


def test_the_replay_samples_each_segment_at_its_step_and_every_waypoint_once(scene):
    """``sample_path``: consecutive samples at most ``step`` apart per joint (continuous joints the short
    way round), every waypoint among them exactly once, in order, and no configuration twice in a row."""
    from types import SimpleNamespace

    from rlgp_exec.planning.validate import sample_path

    model = load_robot("hsr")
    world = SimpleNamespace(robot_model=model)
    rng = np.random.default_rng(0)
    lo, hi = model.limits.lower, model.limits.upper
    q0 = model.home(scene.robot.base, scene.robot.joints)
    for n in (1, 2, 5):
        path = np.array([q0 + rng.uniform(-0.3, 0.3, q0.size) for _ in range(n)])
        path = np.clip(path, np.maximum(lo, -10.0), np.minimum(hi, 10.0))
        qs = sample_path(world, path, 0.01)
        d = np.array([model.limits.difference(b, a) for a, b in itertools.pairwise(qs)]).reshape(-1, q0.size)
        assert np.all(np.abs(d) <= 0.01 + 1e-12)
        assert np.all(np.abs(d).max(axis=1) > 0.0) if n > 1 else len(qs) == 1
        hits = [np.flatnonzero(np.all(np.isclose(qs, w, atol=1e-12), axis=1)) for w in path]
        assert all(h.size == 1 for h in hits)
        at = [int(h[0]) for h in hits]
        assert at == sorted(at) and at[0] == 0 and at[-1] == len(qs) - 1


def test_the_replay_catches_a_held_object_in_the_robots_own_body(scene):
    """The held object is checked against the robot too, but for the links of the hand holding it:
    between the fingers it passes, inside the base and torso it is a collision."""
    import dataclasses

    from rlgp_exec.scene.types import StartState

    model = load_robot("hsr")
    q0 = model.home(scene.robot.base, scene.robot.joints)
    T_world_body = np.eye(4)
    T_world_body[:3, 3] = [q0[0], q0[1], 0.45]
    in_body = np.linalg.inv(model.fk(q0, model.manipulator().tool_frame)) @ T_world_body
    for T_tool_obj, where in ((np.eye(4), None), (in_body, {"base_link", "torso_lift_link"})):
        held = dataclasses.replace(scene, start=StartState.holding("block_blue", T_tool_obj))
        v = validate_plan(held, [Phase(np.array([q0, q0]), "block_blue")])
        hits = {c.rsplit(" ", 1)[-1] for c in v.collisions if "held block_blue ~ robot" in c}
        assert hits == (where or set()), v.collisions


@pytest.mark.parametrize("mesh_rows", [False, True])
def test_keyframes_keep_mesh_fingers_out_of_neighbouring_objects(mesh_rows):
    """The PR2's fingers are meshes: the PyBullet keyframe check must see the objects where they stand,
    or a grasp between close blocks puts a fingertip ~1 cm into the neighbour (pick_place_pr2,
    randomised seed 2: block_a 8 cm from block_c), with the fingertip spheres in the NLP (``mesh_hand``)
    or without. Keyframes also stay inside the joint limits (IPOPT's bound relaxation leaves them up to
    ~1e-8 outside)."""
    from rlgp_exec.planning.sequence import SequenceGeometry
    from rlgp_exec.scene.randomize import randomize
    from rlgp_exec.world.pybullet_world import build_world

    scene = randomize(load_scene(SORTING.parent / "pick_place_pr2.toml"), 2)
    geo = SequenceGeometry(scene, seed=2)
    acts = [a for b in ("block_c", "block_a", "block_b") for a in (Action("pick", b), Action("place", b, "tray"))]
    try:
        kf = solve_keyframes(
            geo.model, scene, geo.q0, acts, seed=2, in_collision=geo._in_collision, ik=geo.ik, hand=geo.hand,
            self_spheres=geo.self_spheres, body=geo.body, lift_room=0.12,
            mesh_hand=geo.mesh_hand if mesh_rows else (),
        )
    finally:
        geo.close()
    assert kf.ok, kf.reason
    lim = geo.model.limits
    finite = np.isfinite(lim.lower) & np.isfinite(lim.upper)
    assert np.all(kf.keyframes[:, finite] >= lim.lower[finite]) and np.all(kf.keyframes[:, finite] <= lim.upper[finite])
    world = build_world(scene, tags=False)
    try:
        world.robot.set_q(kf.keyframes[0])
        hits = [(c.link, world.body_name(c.other_body)) for c in world.robot.contacts(1e-3)]
        assert not [h for h in hits if h[1] in ("block_a", "block_b")], hits
    finally:
        world.close()


def test_finger_spheres_cover_the_whole_finger_box():
    """Every point of a finger's box lies inside one of its spheres (a sparse row lets a wall's edge
    slip between them, ~1 cm into the finger)."""
    from rlgp_exec.planning.nlp.hand import _box_cover

    rng = np.random.default_rng(0)
    for size in (np.array([0.03, 0.012, 0.11]), np.array([0.2, 0.01, 0.02]), np.array([0.02, 0.02, 0.02])):
        spheres = _box_cover(size)
        pts = (rng.uniform(-0.5, 0.5, (4000, 3)) * size)
        corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)]) * size / 2
        for x in np.vstack([pts, corners]):
            assert min(np.linalg.norm(x - c) - r for c, r in spheres) <= 1e-12
        assert max(r for _, r in spheres) <= 0.75 * float(np.sort(size)[1] + np.sort(size)[0])  # not wildly fat


def test_a_graph_seed_in_front_of_a_table_is_pushed_clear_not_dropped():
    """The PR2's graph nodes in front of pick_place_pr2's table stand clear of its real base mesh but
    not of the NLP's footprint circles: dropped, every seed came from behind the table (18 m of base
    path for three blocks). Pushed out, the base is clear and moved no more than needed."""
    import math

    from rlgp_exec.planning.nlp.keyframe_seeds import base_free, push_free
    from rlgp_exec.reach import ReachIK, nominal_q
    from rlgp_exec.robot import load_robot
    from rlgp_exec.scene import load_scene
    from rlgp_exec.scene.geometry import fixture_boxes

    scene = load_scene(Path(__file__).resolve().parents[1] / "sim" / "scenes" / "pick_place_pr2.toml")
    model = load_robot("pr2")
    ik = ReachIK(model, scene, nominal_q(model, scene))
    rects = [(b.T, np.asarray(b.size)) for fx in scene.fixtures for b in fixture_boxes(fx)]
    edge = min(b.T[1, 3] - b.size[1] / 2 for fx in scene.fixtures for b in fixture_boxes(fx))  # front [m]
    rng = np.random.default_rng(0)
    for _ in range(20):
        z = ik.z_of(nominal_q(model, scene))
        z[:3] = [rng.uniform(-0.5, 0.5), edge - rng.uniform(0.25, 0.45), math.pi / 2 + rng.uniform(-0.5, 0.5)]
        pushed = push_free(ik, z, rects)
        assert pushed is not None and base_free(ik, pushed, rects, exact=True)
        assert pushed[1] <= z[1] + 1e-12 and np.allclose(pushed[2:], z[2:])  # away from the table, only the base
        if base_free(ik, z, rects, exact=True):
            assert np.array_equal(pushed, z)
    z[:2] = [0.0, 0.0]  # in the middle of the table: too far to push
    assert push_free(ik, z, rects) is None


def test_pick_between_close_blocks_is_feasible():
    """pick_place_pr2 seed 3: block_c stands 7.6 cm from block_b. The tool sphere (radius 3.5 cm) at the
    grasp kept the arm's 1.5 cm margin from block_b too, 0.3 mm more than the gap allows: every
    candidate failed. At a pick it keeps the open hand's margin; the real fingers pass the PyBullet
    keyframe check (5 mm clearance) against the standing blocks."""
    from rlgp_exec.planning.sequence import SequenceGeometry
    from rlgp_exec.scene.randomize import randomize

    scene = randomize(load_scene(SORTING.parent / "pick_place_pr2.toml"), 3)
    geo = SequenceGeometry(scene, seed=3)
    try:
        kf = solve_keyframes(
            geo.model, scene, geo.q0, [Action("pick", "block_c")], seed=3, in_collision=geo._in_collision,
            ik=geo.ik, hand=geo.hand, self_spheres=geo.self_spheres, body=geo.body, lift_room=0.12,
            seeds=geo._graph_seeds,
        )
        assert kf.ok, kf.reason
        others = {o.name: o.T for o in scene.objects if o.name != "block_c"}
        assert not geo._in_collision(kf.keyframes[0], {}, Action("pick", "block_c"), others)
    finally:
        geo.close()


def test_objects_clear_keeps_the_tool_sphere_at_its_own_margin():
    """Every arm sphere keeps ARM_MARGIN beyond its radius from a standing object; the tool's keeps the
    margin it is given (a pick: HAND_MARGIN)."""

    from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows
    from rlgp_exec.planning.nlp.keyframes import ARM_MARGIN, HAND_MARGIN, _objects_clear
    from rlgp_exec.scene.geometry import Box

    model = load_robot("pr2")
    rs = RobotSymbols(model, model.home(), None, ca.SX.sym("z", 3 + len(model.group(model.manipulator().group))))
    rows = Rows.empty()
    grey = (0.5, 0.5, 0.5, 1.0)
    boxes = [Box("a", (0.05, 0.05, 0.1), np.eye(4), grey), Box("b", (0.1, 0.05, 0.1), np.eye(4), grey)]
    _objects_clear(rs, boxes, rows, HAND_MARGIN)
    assert len(rows.g) == len(boxes) * len(rs.spheres)
    expect = [r + (HAND_MARGIN if f == rs.manip.tool_frame else ARM_MARGIN) for f, r in rs.spheres]
    assert rows.lower == pytest.approx(expect * len(boxes))
    assert all(u == ca.inf for u in rows.upper)


def test_graph_seed_orders_the_free_seeds_by_base_distance():
    """graph_seed: the free seeds nearest the previous keyframe's base first (ties in the given order);
    without a base, the given order; None past the end."""
    from rlgp_exec.planning.nlp.keyframe_seeds import graph_seed
    from rlgp_exec.reach import ReachIK, nominal_q

    scene = load_scene(SORTING.parent / "pick_place_pr2.toml")
    model = load_robot(scene.robot.name)
    ik = ReachIK(model, scene, nominal_q(model, scene))
    rng = np.random.default_rng(0)
    zs = []
    for _ in range(10):  # bases on a ring 1.5-2.5 m from the table's centre: clear of its footprint
        a, r = rng.uniform(-np.pi, np.pi), rng.uniform(1.5, 2.5)
        zs.append(np.r_[r * np.cos(a), r * np.sin(a), rng.uniform(-np.pi, np.pi), ik.home_arm])
    rects = [(fx.T, np.asarray(fx.size)) for fx in scene.fixtures]
    x = np.zeros(3)
    prev = np.array([0.0, -2.0])
    got = [graph_seed(ik, x, lambda _x: zs, rects, i, prev) for i in range(len(zs))]
    d = [float(np.linalg.norm(z[:2] - prev)) for z in got]
    assert d == sorted(d)
    assert sorted(map(tuple, (z[:3] for z in got))) == sorted(map(tuple, (z[:3] for z in zs)))
    assert graph_seed(ik, x, lambda _x: zs, rects, len(zs), prev) is None
    assert np.array_equal(graph_seed(ik, x, lambda _x: zs, rects, 3), zs[3])
    assert graph_seed(ik, x, None, rects, 0, prev) is None


def test_merged_constraints_equal_the_rows():
    """_constraints (common subexpressions merged) evaluates to the rows' own values at random
    configurations of the PR2 near a table and a standing block."""

    from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows, box_clear
    from rlgp_exec.planning.nlp.keyframes import _constraints, _objects_clear
    from rlgp_exec.scene.geometry import fixture_boxes, object_box

    scene = load_scene(SORTING.parent / "pick_place_pr2.toml")
    model = load_robot("pr2")
    n = 3 + len(model.group(model.manipulator().group))
    z = ca.SX.sym("z", n)
    rs = RobotSymbols(model, model.home(), None, z)
    rows = Rows.empty()
    box_clear(rs, [b for fx in scene.fixtures for b in fixture_boxes(fx)], rows, margin=0.015)
    _objects_clear(rs, [object_box(o) for o in scene.objects], rows, 0.008)
    plain, merged = ca.Function("plain", [z], [ca.vertcat(*rows.g)]), ca.Function("merged", [z], [_constraints(rows)])
    rng = np.random.default_rng(0)
    for _ in range(20):
        zv = np.r_[rng.uniform(-1.0, 1.0, 2), rng.uniform(-np.pi, np.pi), rng.uniform(-1.0, 1.0, n - 3)]
        a, b = np.asarray(plain(zv)).ravel(), np.asarray(merged(zv)).ravel()
        assert a.shape == (len(rows.g),)
        assert np.allclose(a, b, rtol=0.0, atol=1e-12)
    assert _constraints(Rows.empty()).shape == (0, 1)


def test_mesh_finger_spheres_hold_every_fingertip_vertex():
    """The PR2's fingertips are meshes: every vertex of their hulls (tool frame) lies inside one of the
    spheres, and the spheres are not much fatter than the tip is thick."""
    import pybullet as p

    from rlgp_exec.planning.nlp.hand import mesh_finger_spheres
    from rlgp_exec.planning.sequence import SequenceGeometry
    from rlgp_exec.robot.pybullet_body import pose_to_matrix

    geo = SequenceGeometry(load_scene(SORTING.parent / "pick_place_pr2.toml"))
    try:
        robot, model = geo.checker.robot, geo.model
        spheres = mesh_finger_spheres(robot, model, geo.q0)
        assert spheres and max(r for _, r in spheres) < 0.025
        robot.set_q(geo.q0)
        T_tool = model.fk(geo.q0, model.manipulator().tool_frame)
        tips = [n for n in model.manipulator().links if "tip" in n]
        assert tips
        for name in tips:
            i = robot.link_index[name]
            st = p.getLinkState(robot.id, i, computeForwardKinematics=True, physicsClientId=robot.client)
            v = np.asarray(p.getMeshData(robot.id, i, collisionShapeIndex=0, flags=p.MESH_DATA_SIMULATION_MESH,
                                         physicsClientId=robot.client)[1])
            # the vertices as PyBullet collides them: inside the link's bounding box
            lo, hi = (np.asarray(b) for b in p.getAABB(robot.id, i, physicsClientId=robot.client))
            w = (pose_to_matrix(st[0], st[1]) @ np.c_[v, np.ones(len(v))].T)[:3].T
            assert np.all(w >= lo - 1e-6) and np.all(w <= hi + 1e-6)
            v_tool = (np.linalg.solve(T_tool, np.c_[w, np.ones(len(w))].T)[:3]).T
            for x in v_tool:
                assert min(np.linalg.norm(x - c) - r for c, r in spheres) <= 1e-9
    finally:
        geo.close()


def test_a_pick_pinned_into_a_neighbour_is_infeasible_before_any_start():
    """pick_place_pr2 seed 3: block_b's grasp point is 41 mm from block_c, the tool sphere needs 43 mm
    (radius 35 + HAND_MARGIN 8): every start of the NLP ended 2 mm short. The check says so at once,
    and not once block_c has been taken away, nor for a neighbour as far as the margin asks."""
    from dataclasses import replace

    from rlgp_exec.planning.nlp.keyframes import HAND_MARGIN, pinned_conflict
    from rlgp_exec.scene.randomize import randomize

    scene = randomize(load_scene(SORTING.parent / "pick_place_pr2.toml"), 3)
    model = load_robot("pr2")
    why = pinned_conflict(model, scene, [Action("pick", "block_b")])
    assert why is not None and "block_c" in why
    c_first = [Action("pick", "block_c"), Action("place", "block_c", "tray"), Action("pick", "block_b")]
    assert pinned_conflict(model, scene, c_first) is None
    res = solve_keyframes(model, scene, model.home(scene.robot.base, scene.robot.joints), [Action("pick", "block_b")])
    assert not res.ok and "block_c" in res.reason
    # block_c turned to face block_b's grasp point and set straight away from it, its near face as far
    # as the sphere needs plus ``extra`` [m]
    b, c = scene.object("block_b"), scene.object("block_c")
    away = (c.T[:2, 3] - b.T[:2, 3]) / np.linalg.norm(c.T[:2, 3] - b.T[:2, 3])
    for extra, expect_conflict in ((0.002, False), (-0.002, True)):
        x, y = b.T[:2, 3] + away * (0.035 + HAND_MARGIN + extra + c.size[0] / 2)
        pose = (float(x), float(y), c.pose[2], float(np.arctan2(away[1], away[0])))
        objs = [replace(o, pose=pose) if o.name == "block_c" else o for o in scene.objects]
        moved = replace(scene, objects=tuple(objs))
        assert (pinned_conflict(model, moved, [Action("pick", "block_b")]) is not None) == expect_conflict


def test_a_box_at_an_expression_pose_gives_the_rows_of_the_same_box_at_a_number():
    """``points_clear_moving`` (an object set down at another keyframe) and ``points_clear`` (a box where
    it stands) agree when the pose is a number, at random hand poses."""
    from scipy.spatial.transform import Rotation

    from rlgp_exec.planning.nlp.factors import Rows
    from rlgp_exec.planning.nlp.hand import points_clear, points_clear_moving
    from rlgp_exec.scene.geometry import Box

    rng = np.random.default_rng(1)
    T_sym = ca.SX.sym("T", 4, 4)
    spheres = [(rng.uniform(-0.05, 0.05, 3), float(rng.uniform(0.01, 0.03))) for _ in range(5)]
    for _ in range(20):
        T_box = np.eye(4)
        T_box[:3, :3] = Rotation.from_euler("z", rng.uniform(-3, 3)).as_matrix()
        T_box[:3, 3] = rng.uniform(-0.2, 0.2, 3)
        size = rng.uniform(0.03, 0.12, 3)
        T_tool = np.eye(4)
        T_tool[:3, :3] = Rotation.random(random_state=rng.integers(1 << 31)).as_matrix()
        T_tool[:3, 3] = rng.uniform(-0.2, 0.2, 3)
        a, b = Rows.empty(), Rows.empty()
        points_clear(ca.SX(ca.DM(T_tool)), spheres, [Box("o", tuple(size), T_box, (0, 0, 0, 1))], a, margin=0.005)
        points_clear_moving(ca.SX(ca.DM(T_tool)), spheres, T_sym, size, b, margin=0.005)
        f = ca.Function("f", [T_sym], [ca.vertcat(*b.g)])
        assert np.allclose(np.asarray(ca.evalf(ca.vertcat(*a.g))).ravel(), np.asarray(f(T_box)).ravel(), atol=1e-12)
        assert a.lower == pytest.approx(b.lower) and a.upper == b.upper


@pytest.mark.parametrize(
    ("scene_file", "acts"),
    [
        ("pick_place_pr2.toml",
         [a for b in ("block_a", "block_b") for a in (Action("pick", b), Action("place", b, "tray"))]),
        ("table_clearing_hsr.toml",
         [Action("take_knob", "cabinet"), Action("open_drawer", "cabinet"), Action("pick", "block"),
          Action("drop", "block", "cabinet")]),
    ],
)
def test_a_partial_restart_keeps_only_keyframes_the_failed_rows_do_not_read(scene_file, acts):
    """Every row of the keyframe NLP reads only its own keyframe and those ``couples`` names (Jacobian
    sparsity), so a restart that keeps the other keyframes where a failed start left them restarts every
    variable a failed row depends on; rows failing at every keyframe mean a fresh start."""
    from rlgp_exec.planning.drawers import drawer_views
    from rlgp_exec.planning.nlp.keyframes import _build, _kept
    from rlgp_exec.planning.sequence import SequenceGeometry

    scene = load_scene(SORTING.parent / scene_file)
    geo = SequenceGeometry(scene, seed=0)
    try:
        prob = _build(geo.model, scene, geo.q0, acts, None, geo.ik, geo.hand, geo.self_spheres, geo.body, 0.12,
                      {o.name: o for o in scene.objects}, drawer_views(scene), geo.mesh_hand)
    finally:
        geo.close()
    J = prob.solver.get_function("nlp_jac_g").sparsity_out(1)
    rows, cols = J.get_triplet()
    assert len(prob.row_keyframe) == J.size1()
    nz = prob.n * prob.K  # after the keyframes: the pose variables (12 each), standing for the keyframes they read
    assert J.size2() == nz + 12 * len(prob.aux_reads)
    for r, c in zip(rows, cols, strict=True):
        k = int(prob.row_keyframe[r])
        read = (c // prob.n,) if c < nz else prob.aux_reads[(c - nz) // 12]
        assert set(read) <= {k, *prob.couples[k]}, (r, prob.labels[r], k, read)
    assert any(prob.couples[k] for k in range(prob.K))  # a place reads its pick, an open its knob grasp
    # the pose variables start where any keyframes put them: their rows hold
    z = np.random.default_rng(0).uniform(np.maximum(prob.lbx[:nz], -3.0), np.minimum(prob.ubx[:nz], 3.0))
    g = np.asarray(prob.solver.get_function("nlp_g")(np.r_[z, np.asarray(prob.aux0(z)).reshape(-1)], 0)).reshape(-1)
    pose_rows = [r for r, label in enumerate(prob.labels) if label.endswith(" pose")]
    assert len(pose_rows) == 12 * len(prob.aux_reads) > 0
    assert np.allclose(g[pose_rows], 0.0, atol=1e-12)
    zk = np.arange(prob.K * prob.n, dtype=float).reshape(prob.K, prob.n)
    own = [k for k in range(prob.K) if prob.targets[k] is not None]
    for k in range(prob.K):
        kept = _kept(prob, zk, prob.row_keyframe == k)
        assert not ({k, *prob.couples[k]} & set(kept))
        assert set(kept) == set(own) - {k, *prob.couples[k]} or kept == {}
        assert all(np.array_equal(kept[j], zk[j]) for j in kept)
    assert _kept(prob, zk, np.ones(len(prob.row_keyframe), bool)) == {}


def test_the_keyframe_hessian_is_the_lagrangians_without_the_clearance_rows_curvature():
    """IPOPT's Hessian of the keyframe NLP is exact for the objective and the task rows (grasp,
    placement, pose variables) and leaves out only the clearance and footprint rows' curvature: it
    equals the exact Hessian of the Lagrangian with those rows' multipliers zeroed, at random points,
    and those rows do have curvature (the exact Hessian with all multipliers differs). Its Jacobian
    (``_jacobian``, rows differentiated in groups) is CasADi's of the whole, entry for entry."""
    from rlgp_exec.planning.drawers import drawer_views
    from rlgp_exec.planning.nlp.keyframes import CURVATURE_FREE, _build
    from rlgp_exec.planning.sequence import SequenceGeometry

    scene = load_scene(SORTING.parent / "pick_place_pr2.toml")
    geo = SequenceGeometry(scene, seed=0)
    acts = [a for b in ("block_a", "block_b") for a in (Action("pick", b), Action("place", b, "tray"))]
    try:
        prob = _build(geo.model, scene, geo.q0, acts, None, geo.ik, geo.hand, geo.self_spheres, geo.body, 0.12,
                      {o.name: o for o in scene.objects}, drawer_views(scene), geo.mesh_hand)
    finally:
        geo.close()
    S = prob.solver
    nx, ng, npar = S.size1_in("x0"), S.size1_in("lam_g0"), S.size1_in("p")
    x, p, lam = ca.SX.sym("x", nx), ca.SX.sym("p", npar), ca.SX.sym("lam", ng)
    f, g = S.get_function("nlp_f")(x, p), S.get_function("nlp_g")(x, p)
    exact = ca.Function("H", [x, p, lam], [ca.triu(ca.hessian(2.0 * f + ca.dot(lam, g), x)[0])])
    jac = ca.Function("J", [x, p], [ca.jacobian(g, x)])
    free = np.array([label.endswith(CURVATURE_FREE) for label in prob.labels])
    assert 0 < free.sum() < ng
    rng = np.random.default_rng(3)
    differs = False
    for _ in range(3):
        z = rng.uniform(np.maximum(prob.lbx, -2.0), np.minimum(prob.ubx, 2.0))
        pv, lv = rng.uniform(0.0, 1.0, npar), rng.normal(size=ng)
        H = np.asarray(ca.densify(S.get_function("nlp_hess_l")(z, pv, 2.0, lv)))
        assert np.allclose(H, np.asarray(ca.densify(exact(z, pv, np.where(free, 0.0, lv)))), atol=1e-9)
        differs |= not np.allclose(H, np.asarray(ca.densify(exact(z, pv, lv))), atol=1e-6)
        J = S.get_function("nlp_jac_g")(z, pv)[1]
        assert J.sparsity() == jac.sparsity_out(0)
        assert np.allclose(np.asarray(ca.densify(J)), np.asarray(ca.densify(jac(z, pv))), rtol=1e-12, atol=1e-12)
    assert differs


def test_boxes_out_of_the_fingers_reach_from_a_site_are_clear_in_the_worst_pose():
    """A box ``_near_site`` leaves out (reach: the site disc's radius, ``finger_reach``, HAND_MARGIN, no
    slack) is clear of every finger sphere by the margin even with the tool on the disc's edge nearest the
    box and the farthest sphere turned straight at it; a box just inside that reach keeps its rows."""
    from scipy.spatial.transform import Rotation

    from rlgp_exec.planning.detour import rect_distance
    from rlgp_exec.planning.nlp.keyframes import HAND_MARGIN, _near_site, finger_reach
    from rlgp_exec.reach.ik import box_sdf
    from rlgp_exec.scene.geometry import Box

    rng = np.random.default_rng(7)
    hand = [(rng.uniform(-0.06, 0.06, 3), float(rng.uniform(0.01, 0.03))) for _ in range(6)]
    c_far, _ = max(hand, key=lambda s: np.linalg.norm(s[0]) + s[1])
    site, r_site = np.array([0.3, -0.2]), 0.05
    reach = r_site + finger_reach(hand) + HAND_MARGIN
    for theta in np.linspace(0.0, 2 * np.pi, 12, endpoint=False):
        yaw, size = rng.uniform(-np.pi, np.pi), rng.uniform(0.05, 0.4, 3)
        T = np.eye(4)
        T[:3, :3] = Rotation.from_euler("z", yaw).as_matrix()
        u = np.array([np.cos(theta), np.sin(theta)])
        for beyond, kept in ((1e-3, False), (-1e-3, True)):
            lo, hi = 0.0, 5.0  # the box's centre along u where its footprint is reach + beyond from the site
            for _ in range(60):
                T[:2, 3] = site + u * (lo + hi) / 2
                lo, hi = (lo, (lo + hi) / 2) if rect_distance(site, T, size) > reach + beyond else ((lo + hi) / 2, hi)
            box = Box("b", tuple(size), T.copy(), (0.0, 0.0, 0.0, 1.0))
            assert (box in _near_site([box], site, reach)) == kept
            if kept:
                continue
            near = T[:2, 3] + T[:2, :2] @ np.clip(T[:2, :2].T @ (site - T[:2, 3]), -size[:2] / 2, size[:2] / 2)
            d = (near - site) / np.linalg.norm(near - site)
            tool = np.r_[site + r_site * d, T[2, 3]]
            R = Rotation.align_vectors([np.r_[d, 0.0]], [c_far])[0].as_matrix()
            for c, r in hand:
                local = np.linalg.solve(T, np.r_[tool + R @ c, 1.0])[:3]
                assert float(box_sdf(local, size / 2)) >= r + HAND_MARGIN - 1e-6


@pytest.mark.parametrize("side", [0, 1])
def test_a_pick_seed_closes_the_fingers_across_the_faces_square_to_its_neighbour(side):
    """With a neighbour off one face of a block, the seed's wrist roll puts the closing axis along the other
    face axis (to within the 15 degree steps), whatever roll the position IK left; without one, z is kept."""
    from rlgp_exec.planning.nlp.keyframe_seeds import face_roll
    from rlgp_exec.reach.ik import ReachIK

    scene = load_scene(SORTING.parent / "pick_place_pr2.toml")
    model = load_robot("pr2")
    q0 = model.home(scene.robot.base, scene.robot.joints)
    ik = ReachIK(model, scene, q0)
    o = scene.object("block_b")
    T_obj = o.T.copy()
    yaw = 0.4
    T_obj[:3, :3] = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
    r = ik.solve(T_obj[:3, 3] + [0.0, 0.0, 0.03], ik.z_of(q0))
    assert r.ok
    z = ik.z_of(r.q)
    neighbour = T_obj[:3, 3] + 0.09 * T_obj[:3, side]
    assert np.array_equal(face_roll(model, ik, z, T_obj, [T_obj[:3, 3] + [0.5, 0.0, 0.0]]), z)
    for turn in (0.0, 0.7, -1.2):
        z0 = z.copy()
        z0[-1] += turn
        zr = face_roll(model, ik, z0, T_obj, [neighbour])
        c = model.fk(ik.q_of(zr), ik.tool)[:3, :3] @ np.asarray(model.manipulator().closing)
        across = T_obj[:2, 1 - side]
        assert abs(c[:2] @ across) / np.linalg.norm(c[:2]) >= np.cos(np.radians(7.6))
@pytest.mark.parametrize("max_tilt", [0.0, 0.3])
def test_approach_rows_bound_the_tilt_with_gradients_at_every_active_row(max_tilt):
    """A hand's approach axis a = Rz(phi) Ry(t) (0, 0, -1) meets ``approach_rows`` exactly when its tilt t is at
    most max_tilt, in every direction phi; the rows active at the vertical hand, with the closing axis's row
    (``closing_bounds``), have linearly independent gradients in the hand's three rotations (a_z = -1 as a row
    has none: IPOPT ended most keyframe solves with ``Error_In_Step_Computation``; c_z = 0 beside a_x = a_y = 0
    is dependent: IPOPT regularised every step, ~3x the time per iteration)."""

    from rlgp_exec.planning.nlp.factors import approach_rows, closing_bounds

    u = ca.SX.sym("u", 3)  # small rotations about x, y and z
    cx, sx, cy, sy = ca.cos(u[0]), ca.sin(u[0]), ca.cos(u[1]), ca.sin(u[1])
    Rx = ca.vertcat(ca.horzcat(1, 0, 0), ca.horzcat(0, cx, -sx), ca.horzcat(0, sx, cx))
    Ry = ca.vertcat(ca.horzcat(cy, 0, sy), ca.horzcat(0, 1, 0), ca.horzcat(-sy, 0, cy))
    Rz = ca.vertcat(ca.horzcat(ca.cos(u[2]), -ca.sin(u[2]), 0), ca.horzcat(ca.sin(u[2]), ca.cos(u[2]), 0),
                    ca.horzcat(0, 0, 1))
    R = Rx @ Ry @ Rz
    c = R @ ca.DM([0.0, 1.0, 0.0])
    rows = [*approach_rows(R @ ca.DM([0.0, 0.0, -1.0]), max_tilt), (c[2], *closing_bounds(max_tilt))]
    g = ca.Function("g", [u], [ca.vertcat(*[r[0] for r in rows])])
    lo, hi = np.array([r[1] for r in rows]), np.array([r[2] for r in rows])

    def ok(t: float, phi: float) -> bool:
        v = np.asarray(g([t * np.cos(phi), t * np.sin(phi), 0.0])).ravel()[:3]  # approach rows; tilt ~ |(a, b)|
        return bool(np.all(v >= lo[:3] - 1e-9) and np.all(v <= hi[:3] + 1e-9))

    for phi in np.linspace(0.0, 2 * np.pi, 13):
        assert ok(0.0, phi)
        assert ok(0.97 * max_tilt, phi) or max_tilt == 0.0
        assert not ok(max_tilt + 0.02, phi)
    v0 = np.asarray(g([0.0, 0.0, 0.0])).ravel()
    active = np.flatnonzero((np.abs(v0 - lo) < 1e-9) | (np.abs(v0 - hi) < 1e-9))
    J = np.asarray(ca.Function("J", [u], [ca.jacobian(g(u), u)])([0.0, 0.0, 0.0]))
    assert np.linalg.matrix_rank(J[active], tol=1e-6) == len(active)


def test_self_rows_are_built_once_per_model_and_arguments_and_equal_self_clear():
    """``self_rows_function`` gives the rows ``self_clear`` builds (values at random configurations, read on
    a ``RobotSymbols``' own forward kinematics), the same function again for arguments with equal
    contents, another for another body, and keeps only the latest SELF_ROWS_KEPT per model."""
    from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows
    from rlgp_exec.planning.nlp.hand import _SELF_ROWS, SELF_ROWS_KEPT, self_clear, self_rows_function
    from rlgp_exec.planning.sequence import SequenceGeometry

    scene = load_scene(SORTING.parent / "pick_place_pr2.toml")
    geo = SequenceGeometry(scene, seed=0)
    geo.close()
    spheres, body = geo.self_spheres, geo.body
    fn = self_rows_function(geo.model, spheres, body)
    assert self_rows_function(geo.model, list(spheres), [(f, b) for f, b in body]) is fn
    assert self_rows_function(geo.model, spheres, body[:-1]) is not fn
    for k in range(SELF_ROWS_KEPT + 2):  # a long-running process keeps only the latest few
        self_rows_function(geo.model, spheres[: k + 1], body)
    assert len(_SELF_ROWS[geo.model]) == SELF_ROWS_KEPT
    n = len(geo.model.group("base")) + len(geo.model.group(geo.model.manipulator().group))
    z = ca.SX.sym("z", n)
    rs = RobotSymbols(geo.model, geo.q0, None, z, frames=fn.frames)
    rows = Rows.empty()
    self_clear(geo.model, rs.q, list(spheres), list(body), rows)
    direct = ca.Function("direct", [z], [ca.vertcat(*rows.g)])
    shared = ca.Function("shared", [z], [fn.rows(rs)])
    assert len(fn.lower) == len(rows.lower) > 0 and np.array_equal(fn.lower, rows.lower)
    rng = np.random.default_rng(0)
    for _ in range(5):
        zv = rng.uniform(-1.0, 1.0, n)
        assert np.allclose(np.asarray(shared(zv)), np.asarray(direct(zv)), atol=1e-12)
    with pytest.raises(KeyError, match="not built"):
        RobotSymbols(geo.model, geo.q0, None, z).frame(body[0][0])


@pytest.mark.parametrize("robot", ["pr2", "hsr"])
def test_vectorised_clearance_rows_equal_the_per_sphere_formulas(robot):
    """``box_clear`` (with and without the tool's own margin) and ``footprint_clear`` (all spheres or
    circles of a box at once) give, row for row,
    the values and bounds of the per-sphere formulas they replace, at random configurations and boxes."""
    from scipy.spatial.transform import Rotation

    from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows, box_clear, footprint_clear
    from rlgp_exec.reach.ik import _smooth_pos, box_sdf
    from rlgp_exec.scene.geometry import Box

    model = load_robot(robot)
    rng = np.random.default_rng(7)
    z = ca.SX.sym("z", len(model.group("base")) + len(model.group(model.manipulator().group)))
    rs = RobotSymbols(model, model.home(), None, z)
    boxes = []
    for i in range(3):
        T = np.eye(4)
        T[:3, :3] = Rotation.random(random_state=int(rng.integers(1 << 31))).as_matrix()
        T[:3, 3] = rng.uniform(-1.0, 1.0, 3)
        boxes.append(Box(f"b{i}", tuple(rng.uniform(0.05, 0.6, 3)), T, (0, 0, 0, 1)))
    rects = [(b.T, np.asarray(b.size)) for b in boxes]
    got, ref = Rows.empty(), Rows.empty()
    box_clear(rs, boxes, got, margin=0.015)
    box_clear(rs, boxes[:1], got, margin=0.015, tool_margin=0.008)
    footprint_clear(rs, rects, got, margin=0.02)
    for b, tool_margin in [*((b, 0.015) for b in boxes), (boxes[0], 0.008)]:  # the per-sphere formulas
        Tinv = np.linalg.inv(b.T)
        for (frame, r), Tk in zip(rs.spheres, rs.sphere_T, strict=True):
            margin = tool_margin if frame == rs.manip.tool_frame else 0.015
            ref.add(box_sdf(ca.DM(Tinv[:3, :3]) @ Tk[:3, 3] + ca.DM(Tinv[:3, 3]), np.asarray(b.size) / 2), r + margin,
                    ca.inf)
    c, s = ca.cos(z[2]), ca.sin(z[2])
    for T, size in rects:
        R2 = T[:2, :2]
        for cx, cy, r in rs.circles:
            wx, wy = z[0] + c * cx - s * cy, z[1] + s * cx + c * cy
            lx = R2[0, 0] * (wx - T[0, 3]) + R2[1, 0] * (wy - T[1, 3])
            ly = R2[0, 1] * (wx - T[0, 3]) + R2[1, 1] * (wy - T[1, 3])
            dx = _smooth_pos(ca.sqrt(lx * lx + 1e-9) - size[0] / 2)
            dy = _smooth_pos(ca.sqrt(ly * ly + 1e-9) - size[1] / 2)
            ref.add(ca.sqrt(dx * dx + dy * dy + 1e-9), r + 0.02, ca.inf)
    assert len(got.g) == len(ref.g) > 0
    assert got.lower == pytest.approx(ref.lower) and got.upper == ref.upper
    f = ca.Function("f", [z], [ca.vertcat(*got.g), ca.vertcat(*ref.g)])
    for _ in range(5):
        a, b = f(rng.uniform(-2.0, 2.0, z.numel()))
        assert np.allclose(np.asarray(a), np.asarray(b), atol=1e-12)


def test_the_keyframe_proxy_catches_an_upper_arm_turned_into_the_chest_or_the_other_shoulder():
    """PR2, the right shoulder pan near its inner limit and the other arm joints random, the left arm tucked:
    every configuration in which PyBullet finds the upper arm more than 5 mm into the torso or into the left
    shoulder violates a self-clearance row of the keyframe NLP (the arm's spheres off the body behind the
    shoulders, the upper arm's off ``inner_obstacles``: the chest between them and the left shoulder), and
    the tucked start holds every row. The body behind the shoulders alone misses some (pick_place_pr2 seeds
    5, 9, 15, 16 lost keyframe starts to them)."""
    import pybullet as p

    from rlgp_exec.planning.nlp.factors import RobotSymbols
    from rlgp_exec.planning.nlp.hand import self_rows_function, upper_arm_spheres
    from rlgp_exec.planning.sequence import SequenceGeometry

    geo = SequenceGeometry(load_scene(SORTING.parent / "pick_place_pr2.toml"), seed=0)
    try:
        model, robot = geo.model, geo.checker.robot
        assert [b.name for _, b in geo.inner] == ["chest", "l_shoulder_pan_link"]
        def of_z(rows):  # (z -> the rows, their bounds), z = base and arm, the other joints at q0
            z = ca.SX.sym("z", len(geo.ik.idx))
            rs = RobotSymbols(model, geo.q0, None, z, frames=rows.frames)
            return ca.Function("rows", [z], [rows.rows(rs)]), rows.lower

        body = of_z(self_rows_function(model, geo.self_spheres, geo.body))
        inner = of_z(self_rows_function(model, upper_arm_spheres(geo.self_spheres), geo.inner))

        def violated(rows, z):
            return bool(np.any(np.asarray(rows[0](z)).ravel() < rows[1]))

        z0 = geo.ik.z_of(geo.q0)
        assert not violated(body, z0) and not violated(inner, z0)
        arm = np.array(model.group(model.manipulator().group))
        lo, hi = np.maximum(model.limits.lower[arm], -3.0), np.minimum(model.limits.upper[arm], 3.0)
        upper_arm = robot.link_index["r_upper_arm_link"]
        into = {robot.link_index["torso_lift_link"], robot.link_index["l_shoulder_pan_link"]}
        rng = np.random.default_rng(3)
        hits, missed_behind_only = 0, 0
        for _ in range(300):
            q = geo.q0.copy()
            q[arm] = rng.uniform(lo, hi)
            q[arm[0]] = rng.uniform(hi[0] - 0.3, hi[0])  # the shoulder pan turned inwards
            robot.set_q(q)
            p.performCollisionDetection(physicsClientId=robot.client)
            contacts = p.getContactPoints(bodyA=robot.id, bodyB=robot.id, physicsClientId=robot.client)
            if not any(upper_arm in (c[3], c[4]) and {c[3], c[4]} & into and c[8] < -0.005 for c in contacts):
                continue
            hits += 1
            z = geo.ik.z_of(q)
            assert violated(body, z) or violated(inner, z), f"the proxy misses the upper arm at {q[arm].round(3)}"
            missed_behind_only += not violated(body, z)
        assert hits >= 10  # the sample reaches the situation at all
        assert missed_behind_only > 0
    finally:
        geo.close()


def test_self_clear_rows_equal_the_per_sphere_per_box_formula():
    """``self_clear`` (built box by box, all spheres at once) gives, row for row, the values and bounds of
    the sphere-by-box formula: each arm sphere's centre in each body box's frame, its ``box_sdf``, bound
    radius + margin; sphere by sphere, each over every box (PR2 right arm against its trunk and the other
    arm, random configurations)."""
    import pybullet as p

    from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows
    from rlgp_exec.planning.nlp.hand import arm_link_spheres, body_obstacles, other_arm_obstacles, self_clear
    from rlgp_exec.reach.ik import box_sdf
    from rlgp_exec.robot.pybullet_body import PyBulletRobot

    model = load_robot("pr2")
    q0 = model.home()
    client = p.connect(p.DIRECT)
    try:
        robot = PyBulletRobot(model, client)
        body = body_obstacles(robot, model, q0, "right_arm") + other_arm_obstacles(robot, model, q0, "right_arm")
    finally:
        p.disconnect(client)
    spheres = arm_link_spheres(model, "right_arm")
    z = ca.SX.sym("z", len(model.group("base")) + len(model.group(model.manipulator("right_arm").group)))
    rs = RobotSymbols(model, q0, "right_arm", z)
    got = Rows.empty()
    self_clear(model, rs.q, list(spheres), list(body), got, margin=0.013)
    frames = tuple(dict.fromkeys([*(f for f, _ in body), *(f for f, _, _ in spheres)]))
    Ts = dict(zip(frames, model.casadi_fk(frames)(rs.q), strict=True))
    ref = Rows.empty()
    for f, c, r in spheres:
        pw = Ts[f][:3, :3] @ ca.DM(c) + Ts[f][:3, 3]
        for bf, b in body:
            pb = Ts[bf][:3, :3].T @ (pw - Ts[bf][:3, 3])
            Tinv = np.linalg.inv(b.T)
            ref.add(box_sdf(ca.DM(Tinv[:3, :3]) @ pb + ca.DM(Tinv[:3, 3]), np.asarray(b.size) / 2), r + 0.013, ca.inf)
    assert len(got.g) == len(ref.g) == len(spheres) * len(body) > 0
    assert got.lower == ref.lower and got.upper == ref.upper
    f_got, f_ref = (ca.Function("g", [z], [ca.vertcat(*rows.g)]) for rows in (got, ref))
    rng = np.random.default_rng(3)
    for _ in range(5):
        zv = rng.uniform(-1.5, 1.5, z.numel())
        np.testing.assert_allclose(np.asarray(f_got(zv)), np.asarray(f_ref(zv)), rtol=0, atol=1e-12)
