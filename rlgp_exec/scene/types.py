"""Scene value objects: what a scene file holds, validated and immutable."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from types import MappingProxyType

import numpy as np
from numpy.typing import NDArray

__all__ = [
    "COLORS",
    "DrawerSpec",
    "Fixture",
    "Goal",
    "Literal",
    "RandomRange",
    "Region",
    "RobotSpec",
    "Scene",
    "SceneObject",
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


@dataclass(frozen=True)
class Scene:
    name: str
    robot: RobotSpec
    fixtures: tuple[Fixture, ...]
    objects: tuple[SceneObject, ...]
    regions: tuple[Region, ...]
    goal: Goal
    source: str  # the file (or label) it was read from

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
        objs = tuple(replace(o, pose=tuple(float(v) for v in poses[o.name])) if o.name in poses else o
                     for o in self.objects)
        return replace(self, objects=objs)
