"""The start base's reach bound (``capabilities.start_reach_gaps``) and the conflicts GNPP states with it
before any NLP (``gnpp.priors``)."""

from __future__ import annotations

import dataclasses

import numpy as np

from rlgp_exec.planning.capabilities import arm_reach, reach_segments, start_reach_gaps
from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.guess import TopIK
from rlgp_exec.planning.gnpp.pntc import add_flags, add_moves, at_start
from rlgp_exec.planning.gnpp.priors import reach_priors
from rlgp_exec.planning.symbolic import GroundAction, ground_scene
from rlgp_exec.robot import load_robot
from rlgp_exec.scene.generate import sorting_scene


def _with_pose(scene, name, xyz):
    objs = tuple(dataclasses.replace(o, pose=(*xyz, o.pose[3])) if o.name == name else o for o in scene.objects)
    return dataclasses.replace(scene, objects=objs)


def test_the_hsr_lift_slides_the_bound():
    """The HSR's first arm joint is its lift: a point high above the base is within reach, one as far
    sideways is not (the bound is a capsule along the lift, not a ball round its origin)."""
    (reach,) = arm_reach("hsr")
    assert reach.slide_m[1] > 0.6 and reach.slide_m[0] == 0.0
    scene = sorting_scene("hsr", 2, 0)
    x, y, yaw = scene.robot.base
    obj = scene.objects[0].name
    high = _with_pose(scene, obj, (x, y, 1.25))
    assert obj not in {g.obj for g in start_reach_gaps(high) if g.target is None}
    side = _with_pose(scene, obj, (x + 1.25 * np.cos(yaw + np.pi / 2), y + 1.25 * np.sin(yaw + np.pi / 2), 0.5))
    assert obj in {g.obj for g in start_reach_gaps(side) if g.target is None}


def test_the_bound_is_sound_at_random_configurations():
    """No configuration of an arm puts its tool past the bound (the triangle inequality, the lift's slide)."""
    rng = np.random.default_rng(0)
    for robot in ("hsr", "pr2"):
        model = load_robot(robot)
        q0 = model.home()
        for a in arm_reach(robot):
            man = next(m for m in model.config.manipulators if m.name == a.manipulator)
            idx = list(model.group(man.group))
            o = model.fk(q0, a.first_joint)[:3, 3]
            lo, hi = np.nan_to_num(model.limits.lower[idx], neginf=-np.pi), np.nan_to_num(model.limits.upper[idx],
                                                                                         posinf=np.pi)
            for _ in range(50):
                q = q0.copy()
                q[idx] = rng.uniform(lo, hi)
                p = model.fk(q, man.tool_frame)[:3, 3]
                d = np.array([0.0, 0.0, 1.0])  # both robots' slides (none for the PR2) are vertical at home
                s = np.clip((p - o) @ d, *a.slide_m)
                assert np.linalg.norm(p - (o + s * d)) <= a.reach_m + 1e-9, (robot, a.manipulator)


def test_priors_forbid_holding_and_placing_before_the_base_moves():
    scene = sorting_scene("pr2", 2, 0)
    gaps = start_reach_gaps(scene)
    far = [g.obj for g in gaps if g.target is None]
    assert far, "the generated PR2 layout has a block out of the start base's reach"
    arms, riders = ["right_arm", "left_arm"], {"left_arm": "right_arm"}
    task = add_flags(add_moves(ground_scene(scene, manipulators=arms), ["right_arm"], riders))
    assert at_start("right_arm") in task.init
    priors = reach_priors(gaps, arms, "right_arm", riders, task.init)
    forbidden = [f for f, _ in priors]
    assert len(priors) == 2 * len(far) + sum(g.target is not None for g in gaps)
    support = next(s for a, o, s in (lit for lit in task.init if lit[0] == "on") if o == far[0])
    for arm in arms:
        pick = GroundAction("pick", (arm, far[0], support))
        from_start = task.simulate([pick])
        assert any(f.occurs_in(from_start) for f in forbidden), arm
        drive = [GroundAction("start-move", ("right_arm",)), GroundAction("end-move", ("right_arm",))]
        moved = task.simulate([*drive, pick])
        assert not any(f.occurs_in(moved) for f in forbidden), arm


def test_the_bound_holds_from_any_base_and_lift():
    """``reach_segments`` at a random configuration: no posture of the arm's joints (the HSR's lift
    included) from that base (and torso) puts the tool past it."""
    rng = np.random.default_rng(1)
    for robot in ("hsr", "pr2"):
        model = load_robot(robot)
        base = list(model.group("base"))
        for _ in range(10):
            q = model.home()
            q[base] = [rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-np.pi, np.pi)]
            for man in model.config.manipulators:
                idx = list(model.group(man.group))
                lo = np.nan_to_num(model.limits.lower[idx], neginf=-np.pi)
                hi = np.nan_to_num(model.limits.upper[idx], posinf=np.pi)
                q_start = q.copy()
                q_start[idx] = rng.uniform(lo, hi)
                (seg,) = (s for s in reach_segments(model, q_start) if s.manipulator == man.name)
                for _ in range(20):
                    q_arm = q_start.copy()
                    q_arm[idx] = rng.uniform(lo, hi)
                    assert seg.gap_m(model.fk(q_arm, man.tool_frame)[:3, 3]) <= 1e-9, (robot, man.name)


def test_a_fixed_base_ik_past_the_bound_tries_no_start():
    """GNPP's keyframe IK with the HSR's base held: a tray 2 m away is answered "unreachable" by the bound
    alone (no IPOPT solve); a block within reach of the held base is still solved."""
    scene = sorting_scene("hsr", 2, 0)
    lib = FactorLib(load_robot("hsr"), scene)
    assert lib.mobile
    ik = TopIK(lib)
    arm, q0 = lib.arms[0], lib.home_q(lib.arms[0])
    T, _, z = lib.surface("tray_blue")
    far = np.array([T[0, 3], T[1, 3], z + 0.03])
    ok, q = ik.solve(arm, far, q0, fixed_base=True)
    assert not ok and np.array_equal(q, q0) and ik.n_solves == 0 and ik.n_beyond == 1
    block = next(o for o in scene.objects if o.name.startswith("block"))
    top = np.asarray(block.pose[:3]) + np.array([0.0, 0.0, block.size[2] / 2 - 0.025])
    ok, q_near = ik.solve(arm, top, q0)  # the base free: it goes to the block
    assert ok
    n = ik.n_solves
    ok, q = ik.solve(arm, top, q_near, fixed_base=True)
    assert ok and ik.n_solves > n and ik.n_beyond == 1
    assert np.linalg.norm(lib.tool_T(arm, q)[:3, 3] - top) < 1e-3
    assert np.allclose(q[:3], q_near[:3])
