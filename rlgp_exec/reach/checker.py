"""The collision checks the reachability graph trusts: configurations and straight edges.

A configuration is valid when the robot keeps ``CLEARANCE`` from every fixture and its links do not
penetrate each other. An edge (a straight line in configuration space) is checked by *conservative
advancement* (``sweep``): at each sample a robot link's distance d to the fixtures is known, and the next
sample is placed where no point of any link can have moved more than its d - CLEARANCE. The bound on
how far a link's point moves sums, over the joints that move that link, a radius per joint (1 m per
metre of a prismatic joint; the base's translation by its length; the robot's reach for the base
yaw; the arm's length for arm joints): a link the edge's joints do not move (the base while only the
arm moves) may stay close to a fixture without slowing the sweep. Between samples the robot
therefore cannot touch a fixture: the check is exact for the continuous motion, not a sampled
approximation. Self-collision, which the bound does not cover, is sampled every ``SELF_STEP`` [rad]
of arm motion.

A check can be split by ``part``: ``"fixed"`` is the robot against the fixtures and the cabinets with
their drawers closed, and itself (what the reachability graph's edge verdicts hold for);
``"changed"`` is everything else (the robot against the movable objects and any cabinet whose drawer
is out, a held object against everything). A motion is free of everything exactly when it is free
of both, so a query that trusts the graph's verdict for the first part checks only the second.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import Literal

import numpy as np
import pybullet as p

from rlgp_exec.planning import budget
from rlgp_exec.reach.sweep import LOOKAHEAD, planar_base, sweep
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.robot.pybullet_body import quat_xyzw
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Box
from rlgp_exec.world.pybullet_world import build_world

__all__ = ["CLEARANCE", "Part", "WorldChecker"]

Part = Literal["all", "fixed", "changed"]

CLEARANCE = 0.005  # [m] between the robot and the fixtures at every checked configuration
SELF_TOLERANCE = 1e-3  # [m] penetration allowed between robot links (touching neighbours)
SELF_STEP = 0.02  # [rad or m] of arm motion between self-collision samples along an edge


def joint_radii(model: RobotModel, arm_group: str, body: int, client: int) -> FloatArray:
    """(nq,) how far [m] a robot point can move per unit of each joint (upper bounds). The base's x and
    y: 1; its yaw: the robot's reach from the vertical axis (the body's links get their own,
    ``WorldChecker._body_yaw_radii``); a prismatic arm joint: 1; a revolute one: the farthest any link it
    moves can be from its origin, the chain's offsets summed from the joint to the link (the distance
    between a link's frame and its parent's is fixed across a revolute or fixed joint; a prismatic one
    adds its travel) plus the link's own reach from its frame (the corners of its collision shapes'
    bounding box at the current posture enclose them)."""
    r = np.full(model.nq, 1.0)
    r[2] = 1.4 if model.name == "pr2" else 1.1  # base axis to the farthest point with the arm out
    index = {n: i for i, n in enumerate(model.joint_names)}
    n = p.getNumJoints(body, physicsClientId=client)
    info = [p.getJointInfo(body, i, physicsClientId=client) for i in range(n)]
    origin = [np.asarray(p.getLinkState(body, i, computeForwardKinematics=True, physicsClientId=client)[4])
              for i in range(n)]
    reach = np.zeros(n)  # each link's own: its frame to the farthest corner of its shapes' bounding box
    for i in range(n):
        if p.getCollisionShapeData(body, i, physicsClientId=client):
            lo, hi = (np.asarray(v) for v in p.getAABB(body, i, physicsClientId=client))
            corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
            reach[i] = float(np.linalg.norm(corners - origin[i], axis=1).max())
    for j in model.group(arm_group):
        link = next(i for i in range(n) if info[i][1].decode() == model.joint_names[j])  # the joint's child
        if info[link][2] == p.JOINT_PRISMATIC:
            continue
        far = 0.0
        for i in range(link, n):  # PyBullet numbers a link after its parent: the joint's subtree follows it
            chain, m = 0.0, i
            while m != link and m >= 0:
                parent = info[m][16]
                chain += float(np.linalg.norm(origin[m] - (origin[parent] if parent >= 0 else origin[m])))
                if info[m][2] == p.JOINT_PRISMATIC:
                    chain += float(info[m][9] - info[m][8])  # its travel
                m = parent
            if m == link:
                far = max(far, chain + reach[i])
        r[index[model.joint_names[j]]] = far
    return r


def vertical_lifts(body: int, client: int, joint_names: tuple[str, ...] | list[str]) -> list[int]:
    """Indices into q of the prismatic ``*lift_joint`` joints moving along their parent's z axis."""
    index = {n: i for i, n in enumerate(joint_names)}
    out = []
    for i in range(p.getNumJoints(body, physicsClientId=client)):
        info = p.getJointInfo(body, i, physicsClientId=client)
        name, kind, axis, parent_rot = info[1].decode(), info[2], info[13], info[15]
        flat = np.allclose(np.abs(np.asarray(parent_rot, float)), [0.0, 0.0, 0.0, 1.0], atol=1e-9)
        if name in index and name.endswith("lift_joint") and kind == p.JOINT_PRISMATIC and flat and (
            np.allclose(np.abs(axis), [0.0, 0.0, 1.0], atol=1e-9)
        ):
            out.append(index[name])
    return out


def link_ancestors(body: int, client: int, joint_names: tuple[str, ...] | list[str]) -> np.ndarray:
    """(n_links + 1, nq) bool: row l + 1 marks the joints of q that move PyBullet link l (row 0: the
    root). A link below a moving joint outside q (a mimic joint) is marked as moved by every joint."""
    index = {n: i for i, n in enumerate(joint_names)}
    n = p.getNumJoints(body, physicsClientId=client)
    rows = np.zeros((n + 1, len(joint_names)), dtype=bool)
    for i in range(n):  # PyBullet numbers a link after its parent
        info = p.getJointInfo(body, i, physicsClientId=client)
        name, kind, parent = info[1].decode(), info[2], info[16]
        rows[i + 1] = rows[parent + 1]
        if name in index:
            rows[i + 1, index[name]] = True
        elif kind != p.JOINT_FIXED:
            rows[i + 1] = True
    return rows


class WorldChecker:
    """``checker(q) -> bool``: True when q collides (or comes within CLEARANCE of a fixture)."""

    def __init__(
        self, scene: Scene, arm_group: str, clearance: float = CLEARANCE, manipulator: str | None = None
    ) -> None:
        """``manipulator``: the arm whose tool holds an attached object and whose fingers may touch a knob
        (None: the robot's first)."""
        self.world = build_world(replace(scene, objects=()), tags=False, collision_only=True)
        self.robot, self.client = self.world.robot, self.world.client
        self.model = self.world.robot_model
        self._fixed_bodies = [*self.world.fixtures.values(), *(c.body for c in self.world.cabinets.values())]
        self._object_bodies: list[int] = []
        self.bodies = list(self._fixed_bodies)
        self.clearance = clearance
        self.radii = joint_radii(self.model, arm_group, self.robot.id, self.client)
        self.arm = np.array(self.model.group(arm_group))
        self.calls = 0
        self.tool = self.model.manipulator(manipulator).tool_frame
        self.attached: tuple[int, FloatArray, float] | None = None  # (body, T_tool_obj, extra reach [m])
        self._held_boxes: dict[tuple[float, ...], tuple[int, list[float]]] = {}  # half extents -> (body, park)
        # the drawers as they are in this world (a replan's start may have one out; the graph's verdicts
        # hold for them closed)
        self.openings = {name: self.world.drawer_opening(name) for name in self.world.cabinets}
        self.knob: int | None = None  # a cabinet body whose drawer the fingers may touch (the hand on its knob)
        hand = set(self.model.manipulator(manipulator).links)
        self._fingers = {i for i, n in self.robot.link_name.items() if n in hand}
        self._moved_by = link_ancestors(self.robot.id, self.client, self.model.joint_names)
        self._tool_row = self.robot.carrier_index(self.tool) + 1  # the tool frame rides on a PyBullet link
        # the body: links that only the base and vertical lifts move (their distance from the base's
        # axis is fixed, so the yaw moves them by that distance per radian, not by the arm's reach)
        self._others = np.ones(self.model.nq, dtype=bool)  # the joints other than the base and the lifts
        self._others[[0, 1, 2, *vertical_lifts(self.robot.id, self.client, self.model.joint_names)]] = False
        self._shaped = np.array([i for i in range(p.getNumJoints(self.robot.id, physicsClientId=self.client))
                                 if p.getCollisionShapeData(self.robot.id, i, physicsClientId=self.client)], dtype=int)
        # the sweep's rows (PyBullet link index + 1) of the links with collision shapes, and row -> entry
        root = p.getCollisionShapeData(self.robot.id, -1, physicsClientId=self.client)
        self.shaped_rows = np.concatenate([[0] if root else [], self._shaped + 1]).astype(int)
        self.row_entry = np.full(self._moved_by.shape[0], -1, dtype=int)
        self.row_entry[self.shaped_rows] = np.arange(self.shaped_rows.size)
        self.finger_links = frozenset(self._fingers)
        self.planar_base = planar_base(self.robot.id, self.client, self.model.joint_names)

    @property
    def world_changed(self) -> bool:
        """True while a drawer is not closed or objects are obstacles: the graph's remembered edge
        verdicts (fixtures only, drawers closed) do not hold."""
        return any(d > 0.0 for d in self.openings.values()) or bool(self._object_bodies)

    def set_objects(self, boxes: list[Box]) -> None:
        """Make these boxes (the movable objects where they stand) obstacles too, replacing earlier ones."""
        for body in self._object_bodies:
            p.removeBody(body, physicsClientId=self.client)
        self._object_bodies = []
        for box in boxes:
            col = p.createCollisionShape(
                p.GEOM_BOX, halfExtents=[float(v) / 2 for v in box.size], physicsClientId=self.client
            )
            pos, quat = box.T[:3, 3].tolist(), quat_xyzw(box.T[:3, :3])
            self._object_bodies.append(p.createMultiBody(0.0, col, -1, pos, quat, physicsClientId=self.client))
        self.bodies = [*self._fixed_bodies, *self._object_bodies]

    def set_drawers(self, openings: dict[str, float]) -> None:
        """Put the drawers at ``openings`` [m] (cabinet name -> opening; unnamed ones stay)."""
        for name, d in openings.items():
            if self.openings.get(name) != d:
                self.world.set_drawer_opening(name, d)
                self.openings[name] = d

    def touch_knob(self, cabinet: str | None) -> None:
        """Let the fingers touch ``cabinet``'s drawer (None: nothing)."""
        self.knob = None if cabinet is None else self.world.cabinets[cabinet].body

    def attach(self, size: FloatArray, T_tool_obj: FloatArray) -> None:
        """Check with a box of ``size`` (3,) held rigidly at T_tool_obj (4, 4) from the tool frame. A box
        of each size is made once and parked below the world, 2 m apart, while not held. Its distances
        are measured pair by pair (``getClosestPoints``, which no collision filter affects); it takes no
        part in the collision detection of the self-collision checks (group and mask 0: one call, where
        a filter against each robot link cost ~0.1 ms each, 9 ms a box on the PR2)."""
        self.detach()
        half = [float(v) / 2 for v in size]
        key = tuple(half)
        if key not in self._held_boxes:
            park = [0.0, 0.0, -10.0 - 2.0 * len(self._held_boxes)]
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=self.client)
            body = p.createMultiBody(0.0, col, -1, park, physicsClientId=self.client)
            p.setCollisionFilterGroupMask(body, -1, 0, 0, physicsClientId=self.client)
            self._held_boxes[key] = (body, park)
        extra = float(np.linalg.norm(T_tool_obj[:3, 3]) + np.linalg.norm(half))
        self.attached = (self._held_boxes[key][0], np.asarray(T_tool_obj, float), extra)

    def detach(self) -> None:
        if self.attached is not None:
            body = self.attached[0]
            park = next(pk for b, pk in self._held_boxes.values() if b == body)
            p.resetBasePositionAndOrientation(body, park, [0.0, 0.0, 0.0, 1.0], physicsClientId=self.client)
            self.attached = None

    def _pairs(self, part: Part) -> list[tuple[int, int]]:
        """(moving body, obstacle body) pairs measured by a check of ``part`` (module docstring)."""
        robot = self.robot.id
        if part == "all":
            robot_vs = self.bodies
        else:
            out = {c.body for name, c in self.world.cabinets.items() if self.openings.get(name, 0.0) != 0.0}
            if part == "fixed":
                robot_vs = [b for b in self._fixed_bodies if b not in out]
            else:
                robot_vs = [*(b for b in self._fixed_bodies if b in out), *self._object_bodies]
        pairs = [(robot, b) for b in robot_vs]
        if self.attached is not None and part != "fixed":
            pairs += [(self.attached[0], b) for b in self.bodies]
        return pairs

    def distance(self, q: FloatArray, part: Part = "all", upto: float = LOOKAHEAD) -> float:
        """Smallest distance [m] from the robot (and a held object) to the fixtures and obstacles, capped
        at ``upto`` [m] (PyBullet measures only that far: a caller asking whether the distance is below a
        threshold passes it); ``part`` restricts the pairs measured (module docstring)."""
        return self._distance(q, self._pairs(part), upto)

    def _place(self, q: FloatArray, pairs: list[tuple[int, int]]) -> None:
        """The robot at q, and the held object in its hand if ``pairs`` measure it."""
        self.robot.set_q(q, only_changed=True)
        if self.attached is not None and any(a == self.attached[0] for a, _ in pairs):
            self.place_held(q)

    def place_held(self, q: FloatArray) -> None:
        """The held object (there must be one) where the hand holds it at q."""
        assert self.attached is not None
        body, T_to, _ = self.attached
        T = self.model.fk(q, self.tool) @ T_to
        p.resetBasePositionAndOrientation(body, T[:3, 3].tolist(), quat_xyzw(T[:3, :3]), physicsClientId=self.client)

    def _distance(self, q: FloatArray, pairs: list[tuple[int, int]], upto: float = LOOKAHEAD) -> float:
        self._place(q, pairs)
        d = upto
        robot = self.robot.id
        for a, b in pairs:
            for c in p.getClosestPoints(a, b, d, physicsClientId=self.client):
                if b == self.knob and a == robot and c[3] in self._fingers and c[4] == 0:
                    continue  # the fingers round the knob
                d = min(d, float(c[8]))
        return d

    def self_collision(self, q: FloatArray) -> bool:
        self.robot.set_q(q, only_changed=True)
        p.performCollisionDetection(physicsClientId=self.client)
        return any(
            c[8] < -SELF_TOLERANCE
            for c in p.getContactPoints(bodyA=self.robot.id, bodyB=self.robot.id, physicsClientId=self.client)
        )

    def __call__(self, q: FloatArray) -> bool:
        budget.check()  # sampling and IK loops check through here
        self.calls += 1
        return self.distance(q, upto=self.clearance) < self.clearance or self.self_collision(q)

    def penetrates(self, q: FloatArray) -> bool:
        """True when q penetrates a fixture or itself (no clearance asked: a grasp may touch the table's
        air gap; the graph's own nodes and edges keep CLEARANCE)."""
        budget.check()
        self.calls += 1
        return self.distance(q, upto=self.clearance) < 0.0 or self.self_collision(q)

    def edge_collides(self, q1: FloatArray, q2: FloatArray, part: Part = "all") -> bool:
        """True when the straight motion q1 -> q2 (yaw the short way) comes within CLEARANCE of a
        fixture or self-collides; ``part`` restricts what is checked (module docstring: "changed" has
        no self-collision samples, "fixed" no objects)."""
        budget.check()
        pairs = self._pairs(part)
        if not pairs:
            return False
        dq = self.model.limits.difference(q2, q1)
        links_bound, held_bound = self._bounds(dq, part, q1)
        arm_len = float(np.abs(dq[self.arm]).max()) if self.arm.size else 0.0
        n_self = max(1, math.ceil(arm_len / SELF_STEP)) if part != "changed" else 0
        # the middle first: closer than the clearance there, the sweep below would stop there too (it
        # cannot step past a configuration that close), so the answer is the same without the sweep
        self.calls += 1
        if self._distance(q1 + 0.5 * dq, pairs, self.clearance) < self.clearance:
            return True
        return sweep(self, q1, dq, pairs, links_bound, held_bound, n_self)

    def _body_yaw_radii(self, q: FloatArray, dq: FloatArray) -> FloatArray:
        """(rows: PyBullet link index + 1) for an edge from q by dq: each body link's (one that only the
        base and vertical lifts move, rigid relative to the base's vertical axis) farthest distance
        [m] from that axis (its bounding box's corners at q); the robot's reach for the other links."""
        radii = np.full(self._moved_by.shape[0], self.radii[2])
        moving = self._others & (dq != 0.0)
        body = self._shaped[~self._moved_by[self._shaped + 1][:, moving].any(axis=1)]
        self.robot.set_q(q, only_changed=True)
        for link in body:
            lo, hi = p.getAABB(self.robot.id, int(link), physicsClientId=self.client)
            dx = max(abs(lo[0] - q[0]), abs(hi[0] - q[0]))
            dy = max(abs(lo[1] - q[1]), abs(hi[1] - q[1]))
            radii[link + 1] = min(radii[link + 1], math.hypot(dx, dy))
        return radii

    def _bounds(self, dq: FloatArray, part: Part, q1: FloatArray | None = None) -> tuple[FloatArray, float]:
        """How far [m] any point of each robot link (rows: PyBullet link index + 1) and of the held object
        can move over an edge of joint motion dq: the base's translation |(dx, dy)| plus, for each
        other joint that moves the link, |dq_j| times that joint's radius (the yaw's, for a body link,
        its distance from the base's axis at q1 when given); the held object's as the tool link's
        with its reach added to each radius (0 when the held object is not checked)."""
        w = np.abs(dq) * self.radii
        w[:3] = 0.0
        trans = float(np.hypot(dq[0], dq[1]))
        links = self._moved_by @ w + trans * self._moved_by[:, :2].any(axis=1)
        if dq[2] != 0.0:  # the yaw: the body links by their own distance from the axis (from q1)
            yaw = self._body_yaw_radii(q1, dq) if q1 is not None else np.full(links.shape, self.radii[2])
            links = links + abs(float(dq[2])) * yaw * self._moved_by[:, 2]
        held = 0.0
        if self.attached is not None and part != "fixed":
            moves = self._moved_by[self._tool_row].copy()
            moves[:2] = False
            held = trans + float(np.abs(dq)[moves] @ (self.radii[moves] + self.attached[2]))
        return links, held

    def close(self) -> None:
        self.world.close()
