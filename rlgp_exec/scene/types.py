"""Scene value objects: what a scene file holds, validated and immutable."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import cast

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "COLORS",
    "IN_HAND",
    "DrawerSpec",
    "Fixture",
    "Goal",
    "Literal",
    "RandomRange",
    "Region",
    "RobotSpec",
    "Scene",
    "SceneObject",
    "StartState",
    "TagSpec",
    "pose_matrix",
]

FloatArray = NDArray[np.float64]
Pose = tuple[float, float, float, float]  # x, y, z (centre) [m], yaw [rad], world frame

#: The named colour palette of scene files (RGBA).
COLORS: Mapping[str, tuple[float, float, float, float]] = MappingProxyType({
    "grey": (0.62, 0.62, 0.64, 1.0),
    "white": (0.95, 0.95, 0.95, 1.0),
    "black": (0.08, 0.08, 0.08, 1.0),
    "red": (0.85, 0.15, 0.13, 1.0),
    "green": (0.15, 0.65, 0.25, 1.0),
    "blue": (0.13, 0.32, 0.85, 1.0),
    "yellow": (0.95, 0.82, 0.12, 1.0),
    "orange": (0.98, 0.55, 0.10, 1.0),
    "purple": (0.55, 0.25, 0.70, 1.0),
    "pink": (0.95, 0.50, 0.70, 1.0),
    "cyan": (0.15, 0.75, 0.85, 1.0),
    "brown": (0.45, 0.30, 0.18, 1.0),
    "wood": (0.72, 0.55, 0.36, 1.0),
})


def pose_matrix(pose: Pose | FloatArray) -> FloatArray:
    """T_world_frame (4, 4) of an [x, y, z, yaw] pose."""
    x, y, z, yaw = (float(v) for v in pose)
    c, s = np.cos(yaw), np.sin(yaw)
    T = np.eye(4)
    T[:2, :2] = [[c, -s], [s, c]]
    T[:3, 3] = (x, y, z)
    return T


@dataclass(frozen=True)
class RobotSpec:
    name: str  # "pr2" | "hsr"
    base: tuple[float, float, float]  # x, y [m], yaw [rad]
    joints: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))


@dataclass(frozen=True)
class DrawerSpec:
    """A drawer opening along the cabinet's local +x."""

    travel: float  # [m], how far it slides out
    knob_height: float  # [m] above the floor: the drawer's front is centred on it
    height: float = 0.15  # [m], outer height of the drawer box


@dataclass(frozen=True)
class Fixture:
    name: str
    shape: str  # "box" | "cylinder"
    size: tuple[float, float, float]  # full extents [m]
    pose: Pose
    color: str
    kind: str = "static"  # "static" | "drawer_cabinet"
    drawer: DrawerSpec | None = None

    @property
    def T(self) -> FloatArray:
        return pose_matrix(self.pose)


@dataclass(frozen=True)
class TagSpec:
    """A tag36h11 marker centred on the object's top face, tag x-axis along the object's x-axis."""

    id: int
    size: float  # black-square edge [m]


@dataclass(frozen=True)
class RandomRange:
    """Ranges drawn per seed, in the support's frame: x, y [m] of the centre, yaw [rad]."""

    x: tuple[float, float] | None = None
    y: tuple[float, float] | None = None
    yaw: tuple[float, float] | None = None


@dataclass(frozen=True)
class SceneObject:
    name: str
    shape: str  # "box" | "cylinder" (size = [d, d, h])
    size: tuple[float, float, float]
    pose: Pose
    color: str
    support: str  # the fixture, object or "<cabinet>.drawer" it rests on
    tag: TagSpec | None = None
    random: RandomRange | None = None

    @property
    def T(self) -> FloatArray:
        return pose_matrix(self.pose)


@dataclass(frozen=True)
class Region:
    """A coloured placement area on a fixture's top face."""

    name: str
    on: str
    size: tuple[float, float]
    offset: tuple[float, float]  # from the fixture's top centre, in its frame [m]
    color: str


@dataclass(frozen=True)
class Literal:
    predicate: str
    args: tuple[str, ...]

    def __str__(self) -> str:
        return f"({' '.join((self.predicate, *self.args))})"


@dataclass(frozen=True)
class Goal:
    literals: tuple[Literal, ...]


#: ``SceneObject.support`` of the object a hand holds (``StartState.held``)
IN_HAND = "<hand>"


@dataclass(frozen=True)
class StartState:
    """The start state beyond the poses: an object in the hand and drawers pulled out. Scene files have
    neither (hands empty, drawers closed); the executive sets them when it replans mid-task."""

    held: str | None = None  # the object in the hand (its ``support`` is IN_HAND)
    arm: str | None = None  # the manipulator holding it (None: the robot's first)
    tool_obj: tuple[float, ...] = ()  # T_tool_obj (4, 4) row-major: the held object in the tool frame
    openings: tuple[tuple[str, float], ...] = ()  # (cabinet, opening [m]) of the drawers not closed

    def __post_init__(self) -> None:
        if (self.held is None) != (len(self.tool_obj) == 0):
            raise ValueError("StartState: held and tool_obj go together")
        if self.held is not None and len(self.tool_obj) != 16:
            raise ValueError(f"StartState: tool_obj needs 16 values (4 x 4 row-major), got {len(self.tool_obj)}")

    @staticmethod
    def holding(obj: str, T_tool_obj: FloatArray, arm: str | None = None,
                openings: Mapping[str, float] | None = None) -> StartState:
        return StartState(obj, arm, tuple(float(v) for v in np.asarray(T_tool_obj).reshape(-1)),
                          tuple(sorted((openings or {}).items())))

    @property
    def T_tool_obj(self) -> FloatArray:
        """(4, 4) the held object in the tool frame; raises if nothing is held."""
        if self.held is None:
            raise ValueError("StartState: nothing is held")
        return np.asarray(self.tool_obj, float).reshape(4, 4)

    def opening(self, cabinet: str) -> float:
        """[m] how far the cabinet's drawer is out at the start (0: closed)."""
        return dict(self.openings).get(cabinet, 0.0)

    @property
    def empty(self) -> bool:
        """Hands empty and drawers closed: what every planner handles."""
        return self.held is None and not any(o > 0.0 for _, o in self.openings)


@dataclass(frozen=True)
class Scene:
    """A task: the robot and where it starts, the fixtures (tables, shelves, cabinets), the movable objects
    and the regions on fixtures, and the goal (literals such as ``(on block_a tray)``). Poses are in the
    world frame, [m] and [rad]. Read from a scene file by :func:`load_scene`; immutable (SENSE makes a new
    one with the sensed poses)."""

    name: str
    robot: RobotSpec
    fixtures: tuple[Fixture, ...]
    objects: tuple[SceneObject, ...]
    regions: tuple[Region, ...]
    goal: Goal
    source: str  # the file (or label) it was read from
    start: StartState = StartState()  # hands empty, drawers closed (scene files); see StartState

    def fixture(self, name: str) -> Fixture:
        for f in self.fixtures:
            if f.name == name:
                return f
        raise KeyError(name)

    def object(self, name: str) -> SceneObject:
        for o in self.objects:
            if o.name == name:
                return o
        raise KeyError(name)

    def region(self, name: str) -> Region:
        for r in self.regions:
            if r.name == name:
                return r
        raise KeyError(name)

    def with_object_poses(self, poses: Mapping[str, Pose]) -> Scene:
        """A copy with some objects moved (no validation: see ``validate_geometry``)."""
        # cast: the four values of a Pose, as Python floats (mypy does not count a generator's items)
        objs = tuple(replace(o, pose=cast(Pose, tuple(float(v) for v in poses[o.name]))) if o.name in poses else o
                     for o in self.objects)
        return replace(self, objects=objs)
