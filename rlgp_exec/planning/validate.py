"""Every plan is replayed before anyone calls it a success: PyBullet, fine resolution, with the objects.

The robot follows each phase's joint path at ``step`` [rad or m] per joint; an object picked at the end
of a phase (or in the hand from the start, ``scene.start``) rides with the hand (its pose relative to
the tool frozen at the grasp) until it is placed.
Collisions are checked for the robot (against the world and itself) and for the held object (against
the world, and against the robot but for the links of the hand holding it: a held object swung
through the robot's own body or its other arm is a collision). The goal literals are then checked in the
final simulated state; a literal this checker cannot evaluate counts as unmet, never as met. Pairs of
robot links that no joint of the plan moves apart are checked at the first configuration only (their
contact cannot change: ``PyBulletRobot.ignore_rigid_pairs``).

Drawers (``drawer_replay``): a phase that ``drives_drawer`` moves the drawer joint with the hand on the
knob (objects inside ride along; leaving the drawer's axis is a violation); the fingers may touch the
drawer of the phase's ``knob``; an object released with ``fall`` drops straight down until it rests.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
import pybullet as p

from rlgp_exec.planning import budget
from rlgp_exec.planning.drawer_replay import DrawerMotion, drawer_literal_holds, settle
from rlgp_exec.planning.margins import REPLAY_CONTACT
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.types import Literal

__all__ = ["Phase", "Validation", "goal_holds", "sample_path", "validate_plan", "validate_with_fallbacks"]

log = logging.getLogger(__name__)
ON_TOLERANCE = 0.01  # [m] an object "on" a surface: its bottom within this of the surface
STEP = 0.01  # [rad or m] the replay's step per joint
TOLERANCE = REPLAY_CONTACT  # [m] penetrations up to this deep are contacts, not collisions


@dataclass(frozen=True)
class Phase:
    """A joint path (n, nq) and what the hand holds while following it; ``grasp``/``release`` say what
    happens to an object when the phase ends."""

    path: FloatArray
    held: str | None
    grasp: str | None = None
    release: str | None = None
    knob: str | None = None  # the hand is at this cabinet's knob: the fingers may touch its drawer
    drives_drawer: bool = False  # the hand holds the knob: the drawer follows it along its axis
    fall: bool = False  # the released object falls onto whatever is below it (a drop into a drawer)
    arm: str | None = None  # the manipulator of held / grasp / release (None: the robot's first)
    carried: tuple[tuple[str, str], ...] = ()  # (manipulator, object) held by the other arms meanwhile
    #: the plan's action (index into ``Plan.actions``) this phase completes: its last configuration is that
    #: action's keyframe, and its gripper event (if any) that action's. None: a phase between actions
    action: int | None = None


@dataclass(frozen=True)
class Validation:
    """A plan's replay in PyBullet: whether it touched anything it must not (``collisions``, as "link ~
    body" pairs), whether the goal holds at its end (``unmet`` literals, with why), and where every object
    (T_world_obj (4, 4)) and drawer (opening [m]) ended."""

    collision_free: bool
    goal_met: bool
    collisions: tuple[str, ...]
    unmet: tuple[str, ...]
    final_poses: dict[str, FloatArray]
    final_openings: dict[str, float] = field(default_factory=dict)  # every drawer's opening [m] at the end

    @property
    def ok(self) -> bool:
        return self.collision_free and self.goal_met


class _Held(NamedTuple):
    """An object in a hand during the replay."""

    tool: str  # the tool frame holding it
    T_tool_obj: FloatArray  # (4, 4) its pose in that frame, frozen at the grasp
    rest: float  # its penetration into its support when it was grasped [m] (<= 0)
    hand: frozenset[str]  # the links of the hand holding it (they may touch it)


def _region_rect(scene: Scene, name: str) -> tuple[FloatArray, tuple[float, float], float] | None:
    # local: planning.nlp.action brings SciPy and OpenCV
    from rlgp_exec.planning.nlp.action import target_surface

    try:
        return target_surface(scene, name)
    except Exception:
        return None


def goal_holds(
    scene: Scene, literal: Literal, poses: dict[str, FloatArray], openings: dict[str, float] | None = None
) -> tuple[bool, str]:
    """(holds, why) for one goal literal in a state given by object poses and drawer openings [m]
    (None: every drawer as the scene file has it, closed)."""
    if literal.predicate in ("in", "open", "closed"):
        return drawer_literal_holds(scene, literal, poses, openings or {})
    if literal.predicate == "on":
        obj, target = literal.args
        o = scene.object(obj)
        T = poses[obj]
        if target in poses:  # stacked on another object
            T2, o2 = poses[target], scene.object(target)
            rect = (T2, (o2.size[0] / 2, o2.size[1] / 2), float(T2[2, 3] + o2.size[2] / 2))
        else:
            region = _region_rect(scene, target)
            if region is None:
                return False, f"{literal}: unknown target {target!r}"
            rect = region
        Tr, half, z = rect
        d = np.linalg.inv(Tr) @ T[:, 3]
        bottom = T[2, 3] - o.size[2] / 2
        ok = abs(bottom - z) <= ON_TOLERANCE and abs(d[0]) <= half[0] and abs(d[1]) <= half[1]
        return ok, f"{literal}: bottom {bottom - z:+.3f} m from the surface, offset ({d[0]:+.3f}, {d[1]:+.3f}) m"
    return False, f"{literal}: the replay cannot check ({literal.predicate} ...) yet"


def validate_plan(
    scene: Scene, phases: Sequence[Phase], step: float = STEP, tolerance: float = TOLERANCE
) -> Validation:
    """The plan's phases replayed in a PyBullet world of ``scene`` (module docstring)."""
    return _replay(scene, phases, {}, step, tolerance)[0]


def validate_with_fallbacks(
    scene: Scene, phases: Sequence[Phase], fallbacks: Mapping[int, Phase]
) -> tuple[Validation, list[Phase], set[int]]:
    """``validate_plan``, where a phase that collides and has a fallback (an optimised path's original:
    level 3, GNPP's trajectories) is replayed again on its fallback, from where it started, and the replay
    goes on; a collision on the fallback ends it. Returns (validation, the phases (fallbacks in place),
    the indices of the phases still on their optimised paths). A fallback has its phase's ends and
    events: the world after it is the one its phase would have left (the replay is kinematic), so one
    pass gives what replaying the whole plan again with the fallback in place would."""
    for k, ph in fallbacks.items():
        if phases[k].drives_drawer or ph.drives_drawer:
            raise ValueError(f"phase {k}: a fallback for a phase that drives a drawer (only motions have them)")
    validation, used = _replay(scene, phases, fallbacks, STEP, TOLERANCE)
    out = [fallbacks[k] if k in used else ph for k, ph in enumerate(phases)]
    return validation, out, set(fallbacks) - used


def _replay(
    scene: Scene, phases: Sequence[Phase], fallbacks: Mapping[int, Phase], step: float, tolerance: float
) -> tuple[Validation, set[int]]:
    """The replay (module docstring): its validation, and the phases replayed on their fallbacks."""
    # local: world.pybullet_world brings OpenCV
    from rlgp_exec.world.pybullet_world import build_world

    world = build_world(scene, tags=False, collision_only=True)
    robot, model, client = world.robot, world.robot_model, world.client
    collisions: list[str] = []
    used: set[int] = set()
    held: dict[str, _Held] = {}  # two arms may hold one object each
    try:
        waypoints = [ph.path for ph in (*phases, *fallbacks.values()) if len(ph.path)]
        if waypoints:  # links no joint of the plan moves apart stay as they start: checked there, then not
            robot.ignore_rigid_pairs(np.vstack(waypoints), tolerance)
        if scene.start.held is not None:  # in the hand from the start (a replan mid-task)
            man = model.manipulator(scene.start.arm)
            held[scene.start.held] = _Held(man.tool_frame, scene.start.T_tool_obj, 0.0, frozenset(man.links))
            robot.ignore_body(world.objects[scene.start.held])
        for k, ph in enumerate(phases):
            collisions = _follow(world, k, ph, held, step, tolerance)
            if collisions and k in fallbacks:
                log.info("phase %d collides in the replay (%s): its path before optimisation instead",
                         k, collisions[0])
                used.add(k)
                ph = fallbacks[k]
                collisions = _follow(world, k, ph, held, step, tolerance)
            if collisions:
                break
            tool = model.manipulator(ph.arm).tool_frame
            fingers = frozenset(model.manipulator(ph.arm).links)
            q_end = ph.path[-1]
            if ph.grasp is not None:
                held_T = np.linalg.inv(model.fk(q_end, tool)) @ world.object_pose(ph.grasp)
                robot.ignore_body(world.objects[ph.grasp])
                # an object may rest a little sunk into its support (scene tolerance): lifting it off
                # must not count that as a collision, going deeper must
                p.performCollisionDetection(physicsClientId=client)
                rest = min(
                    [0.0]
                    + [
                        c[8]
                        for c in p.getContactPoints(bodyA=world.objects[ph.grasp], physicsClientId=client)
                        if c[2] != robot.id
                    ]
                )
                held[ph.grasp] = _Held(tool, held_T, rest, fingers)
            if ph.release is not None:
                robot.ignore_body(world.objects[ph.release], False)
                held.pop(ph.release, None)
                if ph.fall:
                    settle(world, ph.release, robot.id, tolerance)
        poses = {name: world.object_pose(name) for name in world.objects}
        openings = {name: world.drawer_opening(name) for name in world.cabinets}
    finally:
        world.close()
    unmet = []
    for lit in scene.goal.literals:
        ok, why = goal_holds(scene, lit, poses, openings)
        if not ok:
            unmet.append(why)
    validation = Validation(
        not collisions, not unmet and not collisions, tuple(dict.fromkeys(collisions)), tuple(unmet), poses, openings
    )
    return validation, used


def _follow(world, k: int, ph: Phase, held: dict[str, _Held], step: float, tolerance: float) -> list[str]:
    """Phase ``k``'s motion, checked at ``step``: its collisions (the motion stops at the first
    configuration that has any). Moves the robot, the objects in ``held`` and a driven drawer; nothing else."""
    robot, model, client = world.robot, world.robot_model, world.client
    tool = model.manipulator(ph.arm).tool_frame
    fingers = frozenset(model.manipulator(ph.arm).links)
    moving = ([ph.held] if ph.held is not None else []) + [o for _, o in ph.carried]
    for o in moving:
        if o not in held:
            raise ValueError(f"phase {k} holds {o} but nothing was grasped")
    collisions: list[str] = []
    motion = None
    if ph.drives_drawer and ph.knob is not None:
        motion = DrawerMotion.start(world, ph.knob, model.fk(ph.path[0], tool))
    for i, q in enumerate(_samples(world, ph.path, step)):
        if not i & 63:
            budget.check()
        robot.set_q(q)
        if motion is not None:
            violation = motion.follow(world, model.fk(q, tool))
            if violation is not None:
                collisions.append(f"phase {k}: {violation}")
                break
        for o in moving:
            world.set_object_pose(o, model.fk(q, held[o].tool) @ held[o].T_tool_obj)
        for c in robot.contacts(tolerance):
            name = world.body_name(c.other_body) if c.other_body != robot.id else c.other_link
            if ph.grasp is not None and name == ph.grasp and c.link in fingers:
                continue  # the fingers close round the object they are about to grasp
            if ph.knob is not None and name == ph.knob and c.other_link == "0" and c.link in fingers:
                continue  # the fingers round the knob (link 0 of a cabinet: its drawer)
            collisions.append(f"phase {k}: robot {c.link} ~ {name}")
        for o in moving:
            for c in p.getContactPoints(bodyA=world.objects[o], physicsClientId=client):
                if c[2] != robot.id and c[8] < held[o].rest - tolerance:
                    collisions.append(f"phase {k}: held {o} ~ {world.body_name(c[2])}")
                elif c[2] == robot.id and c[8] < -tolerance:
                    link = robot.link_name.get(c[4], str(c[4]))
                    if link not in held[o].hand:
                        collisions.append(f"phase {k}: held {o} ~ robot {link}")
        if collisions:
            break
    return collisions


def sample_path(world, path: FloatArray, step: float) -> FloatArray:
    """The configurations (m, nq) the replay checks along a joint path (n, nq): each segment at ``step``
    [rad or m] per joint or finer, every waypoint once (a segment's first sample is the previous one's
    last: checking it twice cost 12-15 % of a replay)."""
    if len(path) < 2:
        return np.asarray(path, float)
    return np.vstack(list(_samples(world, path, step)))


SAMPLE_CHUNK = 4096  # samples interpolated at once: a very long segment is never held in memory whole


def _samples(world, path: FloatArray, step: float) -> Iterator[FloatArray]:
    """``sample_path``'s configurations, one at a time (in chunks of ``SAMPLE_CHUNK``)."""
    if len(path) < 2:
        yield from np.asarray(path, float)
        return
    limits = world.robot_model.limits
    for k, (a, b) in enumerate(itertools.pairwise(path)):
        d = limits.difference(b, a)
        n = max(1, int(np.ceil(np.abs(d).max() / step)))
        for lo in range(0 if k == 0 else 1, n + 1, SAMPLE_CHUNK):
            t = np.arange(lo, min(lo + SAMPLE_CHUNK, n + 1)) * (1.0 / n)  # as np.linspace(0, 1, n + 1)
            if lo + SAMPLE_CHUNK > n:
                t[-1] = 1.0
            yield from limits.wrap(a[None] + t[:, None] * d[None])
