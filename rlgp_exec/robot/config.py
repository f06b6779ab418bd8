"""Per-robot configuration (``robots/<name>/robot.toml``) as frozen value objects."""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

from rlgp_exec.errors import ModelError
from rlgp_exec.robots import ROBOTS, robot_dir

__all__ = ["BASE_JOINTS", "BaseConfig", "Manipulator", "RobotConfig", "load_robot_config"]

#: The planar base joints prepended to every robot: x, y [m] and yaw [rad] in the world frame.
BASE_JOINTS: tuple[str, str, str] = ("base_x", "base_y", "base_yaw")


@dataclass(frozen=True)
class BaseConfig:
    """Limits of the omnidirectional base, (3,) each: x, y along the base frame's axes, yaw."""

    velocity: tuple[float, float, float]
    acceleration: tuple[float, float, float]
    jerk: tuple[float, float, float]
    footprint_radius: float | None = None
    footprint_half_extents: tuple[float, float] | None = None


@dataclass(frozen=True)
class Manipulator:
    """An arm: its joint group, gripper group, tool/palm frames and gripper positions."""

    name: str
    group: str
    gripper: str
    tool_frame: str
    palm_frame: str
    open: float
    closed: float
    links: tuple[str, ...]
    approach: tuple[float, float, float] = (0.0, 0.0, 1.0)  # tool-frame axis pointing out of the hand
    closing: tuple[float, float, float] = (0.0, 1.0, 0.0)  # tool-frame axis the fingers close along


@dataclass(frozen=True)
class RobotConfig:
    name: str
    urdf: str
    base: BaseConfig
    groups: Mapping[str, tuple[str, ...]]
    manipulators: tuple[Manipulator, ...]
    frames: Mapping[str, str]
    acceleration: Mapping[str, float]
    jerk: Mapping[str, float]
    home: Mapping[str, float]
    allowed_collisions: tuple[tuple[str, str], ...]
    floor_contact: tuple[str, ...]
    folder: Path
    #: joint overrides for looking around (e.g. a raised lift)
    lookout: Mapping[str, float] = field(default_factory=lambda: MappingProxyType({}))
    #: links around the head camera that its own images do not show (the camera looks out of them)
    camera_housing: tuple[str, ...] = ()
    #: joint -> (lower, upper) [rad or m] a planned keyframe keeps within: where the robot's own hulls meet
    #: inside the URDF's limits (a hand against its forearm), which the keyframe NLP's shapes do not model
    keyframe_limits: Mapping[str, tuple[float, float]] = field(default_factory=lambda: MappingProxyType({}))

    def manipulator(self, name: str | None = None) -> Manipulator:
        """The named manipulator, or the first one."""
        if name is None:
            return self.manipulators[0]
        for m in self.manipulators:
            if m.name == name:
                return m
        raise ModelError(f"{self.name}: unknown manipulator {name!r}; valid: {[m.name for m in self.manipulators]}")


def _get(d: Mapping[str, Any], key: str, where: str) -> Any:
    if key not in d:
        raise ModelError(f"{where}: missing '{key}'")
    return d[key]


def load_robot_config(name: str) -> RobotConfig:
    """Read ``robots/<name>/robot.toml``."""
    if name not in ROBOTS:
        raise ModelError(f"unknown robot {name!r}; valid: {list(ROBOTS)}")
    folder = robot_dir(name)
    path = folder / "robot.toml"
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise ModelError(f"{path}: cannot read robot config: {e}") from e
    where = str(path)
    robot = _get(raw, "robot", where)
    base = _get(raw, "base", where)
    he = base.get("footprint_half_extents")
    groups = {k: tuple(v) for k, v in _get(raw, "groups", where).items()}
    manips = tuple(
        Manipulator(
            name=m["name"], group=m["group"], gripper=m["gripper"], tool_frame=m["tool_frame"],
            palm_frame=m["palm_frame"], open=float(m["open"]), closed=float(m["closed"]),
            links=tuple(m.get("links", ())),
            approach=tuple(float(v) for v in m.get("approach", (0.0, 0.0, 1.0))),  # type: ignore[arg-type]
            closing=tuple(float(v) for v in m.get("closing", (0.0, 1.0, 0.0))),  # type: ignore[arg-type]
        )
        for m in _get(raw, "manipulator", where)
    )
    for m in manips:
        for g in (m.group, m.gripper):
            if g not in groups:
                raise ModelError(f"{where}: manipulator {m.name!r} names unknown group {g!r}; valid: {list(groups)}")
    acc = {k: float(v) for k, v in raw.get("acceleration", {}).items()}
    jerk = {k: float(v) for k, v in raw.get("jerk", {}).items()}
    col = raw.get("collision", {})
    planned = {j for joints in groups.values() for j in joints}
    keyframe_limits: dict[str, tuple[float, float]] = {}
    for joint, rng in raw.get("keyframe_limits", {}).items():
        if joint not in planned:
            raise ModelError(f"{where}: keyframe_limits names {joint!r}, in no group; valid: {sorted(planned)}")
        if not (isinstance(rng, list) and len(rng) == 2 and all(isinstance(v, (int, float)) for v in rng)
                and rng[0] < rng[1]):
            raise ModelError(f"{where}: keyframe_limits.{joint} must be [lower, upper] with lower < upper, got {rng!r}")
        keyframe_limits[joint] = (float(rng[0]), float(rng[1]))
    return RobotConfig(
        name=_get(robot, "name", where),
        urdf=_get(robot, "urdf", where),
        base=BaseConfig(
            velocity=tuple(base["velocity"]),
            acceleration=tuple(base["acceleration"]),
            jerk=tuple(base["jerk"]),
            footprint_radius=base.get("footprint_radius"),
            footprint_half_extents=tuple(he) if he is not None else None,
        ),
        groups=MappingProxyType(groups),
        manipulators=manips,
        frames=MappingProxyType(dict(raw.get("frames", {}))),
        acceleration=MappingProxyType(acc),
        jerk=MappingProxyType(jerk),
        home=MappingProxyType({k: float(v) for k, v in raw.get("home", {}).items()}),
        allowed_collisions=tuple((a, b) for a, b in col.get("allowed", [])),
        floor_contact=tuple(col.get("floor_contact", ())),
        folder=folder,
        lookout=MappingProxyType({k: float(v) for k, v in raw.get("lookout", {}).items()}),
        camera_housing=tuple(raw.get("camera", {}).get("housing", ())),
        keyframe_limits=MappingProxyType(keyframe_limits),
    )
