"""Scenes: the TOML contract (see ``loader``), value objects, geometry and randomisation."""

from rlgp_exec.scene.geometry import Box, CabinetGeometry, cabinet_geometry, fixture_boxes, object_box, region_box
from rlgp_exec.scene.literals import PREDICATES, parse_literal
from rlgp_exec.scene.loader import load_scene, scene_from_dict
from rlgp_exec.scene.randomize import randomize, scene_hash
from rlgp_exec.scene.serialize import scene_to_dict
from rlgp_exec.scene.types import (
    COLORS,
    IN_HAND,
    DrawerSpec,
    Fixture,
    Goal,
    Literal,
    RandomRange,
    Region,
    RobotSpec,
    Scene,
    SceneObject,
    StartState,
    TagSpec,
    pose_matrix,
)

__all__ = [
    "COLORS",
    "IN_HAND",
    "PREDICATES",
    "Box",
    "CabinetGeometry",
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
    "cabinet_geometry",
    "fixture_boxes",
    "load_scene",
    "object_box",
    "parse_literal",
    "pose_matrix",
    "randomize",
    "region_box",
    "scene_from_dict",
    "scene_hash",
    "scene_to_dict",
]
