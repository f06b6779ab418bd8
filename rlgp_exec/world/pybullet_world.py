"""PyBullet worlds built from scene files: floor, fixtures, drawer cabinets, objects, regions, robot.

One :class:`World` owns one PyBullet client (DIRECT by default: headless). Every body is built from
the scene layer's geometry (``rlgp_exec.scene.geometry``), so the planners' collision model and the
simulator agree box for box. A drawer cabinet is one multibody: the carcass is its fixed base, the
drawer (with its knob) a link on a prismatic joint along the cabinet's local +x.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
import pybullet as p
from numpy.typing import NDArray

from rlgp_exec.errors import RlgpError
from rlgp_exec.robot import RobotModel, load_robot
from rlgp_exec.robot.pybullet_body import PyBulletRobot, pose_to_matrix, quat_xyzw
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import TAG_LIFT, Box, cabinet_geometry, fixture_boxes, object_box, region_box
from rlgp_exec.world.tags import tag_files, tag_quad_size

__all__ = ["CabinetBody", "World", "build_world", "matrix_to_pose"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

OBJECT_MASS = 0.2  # [kg]
TAG_LINK = 0  # link index of a tagged object's tag quad
DRAWER_MASS = 1.0  # [kg]


def matrix_to_pose(T: FloatArray) -> tuple[list[float], list[float]]:
    """PyBullet (position, quaternion xyzw) of T (4, 4) (a rotation: no orthogonalisation; the replay
    calls this at every step for a held object)."""
    return T[:3, 3].tolist(), quat_xyzw(T[:3, :3])


@dataclass(frozen=True)
class CabinetBody:
    body: int
    drawer_joint: int  # PyBullet joint index of the drawer's prismatic joint
    travel: float  # [m]


@dataclass
class World:
    """A scene instantiated in PyBullet."""

    client: int
    scene: Scene
    robot_model: RobotModel
    robot: PyBulletRobot
    floor: int
    fixtures: dict[str, int] = field(default_factory=dict)
    cabinets: dict[str, CabinetBody] = field(default_factory=dict)
    objects: dict[str, int] = field(default_factory=dict)
    regions: dict[str, int] = field(default_factory=dict)
    owns_client: bool = True

    # ------------------------------------------------------------------ objects and drawers
    def tag_pose(self, name: str) -> FloatArray:
        """T_world_tag (4, 4) of a tagged object's quad (ground truth for perception)."""
        body = self._object(name)
        if p.getNumJoints(body, physicsClientId=self.client) == 0:
            raise RlgpError(f"object {name!r} has no tag in this world")
        st = p.getLinkState(body, TAG_LINK, computeForwardKinematics=True, physicsClientId=self.client)
        return pose_to_matrix(st[4], st[5])

    def object_pose(self, name: str) -> FloatArray:
        """T_world_object (4, 4)."""
        body = self._object(name)
        pos, quat = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        return pose_to_matrix(pos, quat)

    def set_object_pose(self, name: str, T_world_object: FloatArray) -> None:
        pos, quat = matrix_to_pose(T_world_object)
        p.resetBasePositionAndOrientation(self._object(name), pos, quat, physicsClientId=self.client)

    def drawer_opening(self, cabinet: str) -> float:
        """How far the drawer is out [m] (0 = closed)."""
        c = self._cabinet(cabinet)
        return float(p.getJointState(c.body, c.drawer_joint, physicsClientId=self.client)[0])

    def set_drawer_opening(self, cabinet: str, opening: float) -> None:
        c = self._cabinet(cabinet)
        if not (0.0 <= opening <= c.travel + 1e-9):
            raise RlgpError(f"drawer of {cabinet!r}: opening {opening:.3f} m outside [0, {c.travel}]")
        p.resetJointState(c.body, c.drawer_joint, opening, 0.0, physicsClientId=self.client)

    def _object(self, name: str) -> int:
        try:
            return self.objects[name]
        except KeyError:
            raise RlgpError(f"unknown object {name!r}; valid: {sorted(self.objects)}") from None

    def _cabinet(self, name: str) -> CabinetBody:
        try:
            return self.cabinets[name]
        except KeyError:
            raise RlgpError(f"unknown drawer cabinet {name!r}; valid: {sorted(self.cabinets)}") from None

    # ------------------------------------------------------------------ checks
    def body_name(self, body: int) -> str:
        for table in (self.fixtures, self.objects):
            for n, b in table.items():
                if b == body:
                    return n
        for n, c in self.cabinets.items():
            if c.body == body:
                return n
        return "floor" if body == self.floor else ("robot" if body == self.robot.id else f"body {body}")

    def penetrations(self, tolerance: float = 1e-3) -> list[str]:
        """Every penetration deeper than ``tolerance`` [m] in the world, described in words."""
        p.performCollisionDetection(physicsClientId=self.client)
        out = [
            f"robot {c.link} ~ {self.body_name(c.other_body) if c.other_body != self.robot.id else c.other_link}"
            f" ({-c.distance * 1000:.1f} mm)"
            for c in self.robot.contacts(tolerance, refresh=False)
        ]
        for name, body in self.objects.items():
            for c in p.getContactPoints(bodyA=body, physicsClientId=self.client):
                if c[8] < -tolerance and c[2] != self.robot.id:
                    other = self.body_name(c[2])
                    if other in self.objects and other < name:
                        continue  # report each object pair once
                    out.append(f"object {name} ~ {other} ({-c[8] * 1000:.1f} mm)")
        return out

    def close(self) -> None:
        if self.owns_client and p.isConnected(self.client):
            p.disconnect(self.client)


# ---------------------------------------------------------------------- builders
def _rgba(color: Sequence[float]) -> list[float]:
    return [float(c) for c in color]


def _box_shapes(client: int, boxes: Sequence[Box], T_ref: FloatArray, collision: bool = True) -> tuple[int, int]:
    """Compound collision and visual shapes of ``boxes`` (poses given in the frame T_ref)."""
    inv = np.linalg.inv(T_ref)
    half, pos, orn, rgba = [], [], [], []
    for b in boxes:
        T = inv @ b.T
        ps, qt = matrix_to_pose(T)
        half.append([float(s) / 2 for s in b.size])
        pos.append(ps)
        orn.append(qt)
        rgba.append(_rgba(b.color))
    n = len(boxes)
    col = -1
    if collision:
        col = p.createCollisionShapeArray(
            [p.GEOM_BOX] * n, halfExtents=half, collisionFramePositions=pos,
            collisionFrameOrientations=orn, physicsClientId=client,
        )
    vis = p.createVisualShapeArray(
        [p.GEOM_BOX] * n, halfExtents=half, visualFramePositions=pos, visualFrameOrientations=orn,
        rgbaColors=rgba, physicsClientId=client,
    ) if n > 1 else p.createVisualShape(
        p.GEOM_BOX, halfExtents=half[0], visualFramePosition=pos[0], visualFrameOrientation=orn[0],
        rgbaColor=rgba[0], physicsClientId=client,
    )
    return col, vis


def _static_body(client: int, boxes: Sequence[Box], collision: bool = True) -> int:
    col, vis = _box_shapes(client, boxes, np.eye(4), collision)
    return p.createMultiBody(0.0, col, vis, physicsClientId=client)


def _cabinet_body(client: int, fixture) -> CabinetBody:
    g = cabinet_geometry(fixture)
    T_world_base = g.T_world_cabinet
    base_col, base_vis = _box_shapes(client, g.carcass, T_world_base)
    T_base_drawer = np.linalg.inv(T_world_base) @ g.T_world_drawer_closed
    drawer_boxes = [Box(b.name, b.size, g.T_world_drawer_closed @ b.T, b.color) for b in g.drawer]
    d_col, d_vis = _box_shapes(client, drawer_boxes, g.T_world_drawer_closed)
    base_pos, base_quat = matrix_to_pose(T_world_base)
    link_pos, link_quat = matrix_to_pose(T_base_drawer)
    axis_drawer = g.T_world_drawer_closed[:3, :3].T @ np.asarray(g.axis_world, float)
    body = p.createMultiBody(
        baseMass=0.0, baseCollisionShapeIndex=base_col, baseVisualShapeIndex=base_vis,
        basePosition=base_pos, baseOrientation=base_quat,
        linkMasses=[DRAWER_MASS], linkCollisionShapeIndices=[d_col], linkVisualShapeIndices=[d_vis],
        linkPositions=[link_pos], linkOrientations=[link_quat],
        linkInertialFramePositions=[[0, 0, 0]], linkInertialFrameOrientations=[[0, 0, 0, 1]],
        linkParentIndices=[0], linkJointTypes=[p.JOINT_PRISMATIC], linkJointAxis=[axis_drawer.tolist()],
        physicsClientId=client,
    )
    return CabinetBody(body=body, drawer_joint=0, travel=float(g.travel))


def _object_body(client: int, obj, tags: bool) -> int:
    """A dynamic body; a tagged object carries its tag quad as a fixed child link (link 0)."""
    b = object_box(obj)
    half = [float(s) / 2 for s in b.size]
    if obj.shape == "cylinder":
        col = p.createCollisionShape(p.GEOM_CYLINDER, radius=half[0], height=float(b.size[2]), physicsClientId=client)
        vis = p.createVisualShape(p.GEOM_CYLINDER, radius=half[0], length=float(b.size[2]),
                                  rgbaColor=_rgba(b.color), physicsClientId=client)
    else:
        col = p.createCollisionShape(p.GEOM_BOX, halfExtents=half, physicsClientId=client)
        vis = p.createVisualShape(p.GEOM_BOX, halfExtents=half, rgbaColor=_rgba(b.color), physicsClientId=client)
    pos, quat = matrix_to_pose(b.T)
    if not (tags and obj.tag is not None):
        return p.createMultiBody(OBJECT_MASS, col, vis, pos, quat, physicsClientId=client)
    quad, png = tag_files(obj.tag.id)
    edge = tag_quad_size(obj.tag.size)
    tag_vis = p.createVisualShape(p.GEOM_MESH, fileName=str(quad), meshScale=[edge, edge, 1.0],
                                  rgbaColor=[1, 1, 1, 1], physicsClientId=client)
    body = p.createMultiBody(
        OBJECT_MASS, col, vis, pos, quat,
        linkMasses=[0.001], linkCollisionShapeIndices=[-1], linkVisualShapeIndices=[tag_vis],
        linkPositions=[[0.0, 0.0, half[2] + TAG_LIFT]], linkOrientations=[[0, 0, 0, 1]],
        linkInertialFramePositions=[[0, 0, 0]], linkInertialFrameOrientations=[[0, 0, 0, 1]],
        linkParentIndices=[0], linkJointTypes=[p.JOINT_FIXED], linkJointAxis=[[0, 0, 1]],
        physicsClientId=client,
    )
    texture = p.loadTexture(str(png), physicsClientId=client)
    p.changeVisualShape(body, TAG_LINK, textureUniqueId=texture, physicsClientId=client)
    return body


def build_world(
    scene: Scene, client: int | None = None, *, tags: bool = True, collision_only: bool = False
) -> World:
    """Instantiate ``scene`` in PyBullet (a new DIRECT client unless ``client`` is given). ``collision_only``:
    a world no camera renders (collision checks, replays) gets the robot's collision-only body
    (``PyBulletRobot``)."""
    owns = client is None
    cid = p.connect(p.DIRECT) if client is None else client
    try:
        p.setGravity(0, 0, -9.81, physicsClientId=cid)
        floor_col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[20, 20, 0.05], physicsClientId=cid)
        floor_vis = p.createVisualShape(p.GEOM_BOX, halfExtents=[20, 20, 0.05], rgbaColor=[0.86, 0.84, 0.80, 1],
                                        physicsClientId=cid)
        floor = p.createMultiBody(0.0, floor_col, floor_vis, [0, 0, -0.05], physicsClientId=cid)
        model = load_robot(scene.robot.name)
        robot = PyBulletRobot(model, cid, collision_only=collision_only)
        robot.ignore_floor(floor)
        robot.set_q(model.home(scene.robot.base, scene.robot.joints))
        world = World(cid, scene, model, robot, floor, owns_client=owns)
        for fx in scene.fixtures:
            if fx.kind == "drawer_cabinet":
                world.cabinets[fx.name] = _cabinet_body(cid, fx)
                if scene.start.opening(fx.name) > 0.0:  # a drawer already out (a replan mid-task)
                    world.set_drawer_opening(fx.name, scene.start.opening(fx.name))
            else:
                world.fixtures[fx.name] = _static_body(cid, fixture_boxes(fx))
        for rg in scene.regions:
            world.regions[rg.name] = _static_body(cid, [region_box(scene, rg)], collision=False)
        for obj in scene.objects:
            world.objects[obj.name] = _object_body(cid, obj, tags)
        log.info("built world %s: %d fixtures, %d cabinets, %d objects", scene.name,
                 len(world.fixtures), len(world.cabinets), len(world.objects))
        return world
    except BaseException:
        if owns:
            p.disconnect(cid)
        raise


