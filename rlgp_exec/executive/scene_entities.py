"""The world and the plan as Foxglove scene entities (``foxglove.SceneUpdate``, protobuf, from foxglove-sdk).

Entities (ids): ``fixture/<name>`` (boxes, cylinders, a cabinet's carcass) and ``drawer/<cabinet>`` in
``world``, at their sensed opening; ``region/<name>`` (flat boxes on their fixture); ``object/<name>``
in the object's own frame (``frame_locked``: TF moves it); ``plan/base`` (the base's path on the floor)
and ``plan/<manipulator>`` (the tool frame's path), each path the plan's joint paths through FK.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import foxglove.messages as fm
import numpy as np
from scipy.spatial.transform import Rotation

from rlgp_exec.executive.robot_tf import RobotTf
from rlgp_exec.executive.ros_messages import WORLD
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene, cabinet_geometry
from rlgp_exec.scene.geometry import Box, fixture_boxes, region_box
from rlgp_exec.scene.types import COLORS

__all__ = ["SCHEMA", "drawer_update", "plan_update", "scene_update"]

SCHEMA = fm.SceneUpdate.get_schema()  # name foxglove.SceneUpdate, encoding protobuf
PLAN_COLORS = ((0.1, 0.4, 1.0, 1.0), (1.0, 0.5, 0.0, 1.0), (0.0, 0.7, 0.3, 1.0))  # base, first and second arm
MAX_PATH_POINTS = 500  # a path drawn with more points is thinned to about this many (each tool point: an FK)


def _time(t: float) -> fm.Timestamp:
    sec, ns = divmod(round(t * 1e9), 1_000_000_000)
    return fm.Timestamp(int(sec), int(ns))


def _pose(T: FloatArray) -> fm.Pose:
    x, y, z, w = Rotation.from_matrix(np.asarray(T, float)[:3, :3]).as_quat()
    return fm.Pose(
        position=fm.Vector3(x=float(T[0, 3]), y=float(T[1, 3]), z=float(T[2, 3])),
        orientation=fm.Quaternion(x=float(x), y=float(y), z=float(z), w=float(w)),
    )


def _color(rgba: Sequence[float]) -> fm.Color:
    r, g, b, a = (float(v) for v in rgba)
    return fm.Color(r=r, g=g, b=b, a=a)


def _cube(b: Box, T: FloatArray | None = None) -> fm.CubePrimitive:
    sx, sy, sz = b.size
    size = fm.Vector3(x=sx, y=sy, z=sz)
    return fm.CubePrimitive(pose=_pose(b.T if T is None else T), size=size, color=_color(b.color))


def _entity(t: float, eid: str, frame: str = WORLD, **prims: Any) -> fm.SceneEntity:
    return fm.SceneEntity(timestamp=_time(t), frame_id=frame, id=eid, frame_locked=frame != WORLD, **prims)


def _drawer(t: float, scene: Scene, cabinet: str, opening: float) -> fm.SceneEntity:
    g = cabinet_geometry(scene.fixture(cabinet))
    T = g.T_world_drawer(opening)
    return _entity(t, f"drawer/{cabinet}", cubes=[_cube(b, T @ b.T) for b in g.drawer])


def scene_update(t: float, scene: Scene, openings: Mapping[str, float] | None = None) -> bytes:
    """Every fixture, drawer (at ``openings`` [m], closed by default), region and object of ``scene``."""
    openings = openings or {}
    ents = []
    for fx in scene.fixtures:
        if fx.kind == "drawer_cabinet":
            ents.append(_entity(t, f"fixture/{fx.name}", cubes=[_cube(b) for b in cabinet_geometry(fx).carcass]))
            ents.append(_drawer(t, scene, fx.name, openings.get(fx.name, 0.0)))
        elif fx.shape == "cylinder":
            d, _, h = fx.size
            ents.append(_entity(t, f"fixture/{fx.name}", cylinders=[fm.CylinderPrimitive(
                pose=_pose(fx.T), size=fm.Vector3(x=d, y=d, z=h), bottom_scale=1.0, top_scale=1.0,
                color=_color(COLORS[fx.color]))]))
        else:
            ents.append(_entity(t, f"fixture/{fx.name}", cubes=[_cube(b) for b in fixture_boxes(fx)]))
    for r in scene.regions:
        ents.append(_entity(t, f"region/{r.name}", cubes=[_cube(region_box(scene, r))]))
    for o in scene.objects:
        sx, sy, sz = o.size
        size, color, origin = fm.Vector3(x=sx, y=sy, z=sz), _color(COLORS[o.color]), _pose(np.eye(4))
        prims: dict[str, Any] = (
            {"cylinders": [fm.CylinderPrimitive(pose=origin, size=size, bottom_scale=1.0, top_scale=1.0, color=color)]}
            if o.shape == "cylinder" else {"cubes": [fm.CubePrimitive(pose=origin, size=size, color=color)]}
        )
        ents.append(_entity(t, f"object/{o.name}", frame=o.name, **prims))
    return fm.SceneUpdate(entities=ents).encode()


def drawer_update(t: float, scene: Scene, openings: Mapping[str, float]) -> bytes:
    """The drawers of ``openings`` (cabinet: [m] out) moved there."""
    return fm.SceneUpdate(entities=[_drawer(t, scene, c, o) for c, o in openings.items()]).encode()


def _line(t: float, eid: str, points: FloatArray, rgba: Sequence[float]) -> fm.SceneEntity:
    step = max(1, len(points) // MAX_PATH_POINTS)
    pts = [fm.Point3(x=float(p[0]), y=float(p[1]), z=float(p[2])) for p in points[::step]]
    line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.01, points=pts, color=_color(rgba))
    return _entity(t, eid, lines=[line])


def plan_update(t: float, robot: RobotTf, paths: Sequence[FloatArray]) -> bytes:
    """The plan's joint paths (each (n, nq)) as the base's path (2 cm above the floor) and each tool's."""
    ents, model = [], robot.model
    if paths:
        q = np.concatenate([np.asarray(p, float).reshape(-1, model.nq) for p in paths])
        base = np.column_stack([q[:, 0], q[:, 1], np.full(len(q), 0.02)])
        ents.append(_line(t, "plan/base", base, PLAN_COLORS[0]))
        step = max(1, len(q) // MAX_PATH_POINTS)
        for k, m in enumerate(model.config.manipulators):
            tool = robot.positions(q[::step], m.tool_frame)
            ents.append(_line(t, f"plan/{m.name}", tool, PLAN_COLORS[1 + k % 2]))
    return fm.SceneUpdate(entities=ents).encode()
