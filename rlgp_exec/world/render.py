"""Pictures of a world for people: an overview, a top view, or the robot's head camera."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import NamedTuple

import cv2
import numpy as np
import pybullet as p

from rlgp_exec.errors import RlgpError
from rlgp_exec.scene import Scene
from rlgp_exec.world.pybullet_world import World, build_world

__all__ = ["VIEWS", "Camera", "camera", "overview_framing", "render_scene_png", "render_world"]

log = logging.getLogger(__name__)
VIEWS = ("overview", "top", "robot")


def _scene_bounds(world: World) -> tuple[np.ndarray, np.ndarray]:
    lo, hi = np.full(3, np.inf), np.full(3, -np.inf)
    bodies = [*world.fixtures.values(), *world.objects.values(), *(c.body for c in world.cabinets.values())]
    for b in [*bodies, world.robot.id]:
        for link in range(-1, p.getNumJoints(b, physicsClientId=world.client)):
            a, z = p.getAABB(b, link, physicsClientId=world.client)
            lo, hi = np.minimum(lo, a), np.maximum(hi, z)
    return lo, hi


def overview_framing(world: World) -> tuple[list[float], float, float, float]:
    """The overview's camera: target (3,) [m], distance [m], yaw and pitch [deg] (PyBullet's convention),
    behind and above the robot's start heading, the whole scene in view."""
    lo, hi = _scene_bounds(world)
    span = float(np.max(hi[:2] - lo[:2]))
    yaw = float(np.degrees(world.scene.robot.base[2])) - 35.0
    return ((lo + hi) / 2).tolist(), 1.0 * span + 1.2, yaw, -38.0


class Camera(NamedTuple):
    """PyBullet's view and projection matrices (16 floats each, column-major)."""

    view: tuple[float, ...]
    projection: tuple[float, ...]


def camera(world: World, width: int = 960, height: int = 720, view: str = "overview") -> Camera:
    """The camera ``view`` of the world as it is now; an animation keeps one, so the view does not follow the
    robot's bounds from frame to frame (the ``robot`` view is the head camera: it moves with the head)."""
    if view not in VIEWS:
        raise RlgpError(f"unknown view {view!r}; valid: {list(VIEWS)}")
    if width < 16 or height < 16:
        raise RlgpError(f"image size {width}x{height} too small (min 16x16)")
    aspect = width / height
    if view == "robot":
        T = world.robot_model.fk(world.robot.get_q(), world.robot_model.config.frames["camera"])
        eye = T[:3, 3]
        target = eye + T[:3, 2]  # optical z forward
        up = -T[:3, 1]  # optical y down
        view_m = p.computeViewMatrix(eye.tolist(), target.tolist(), up.tolist())
        proj = p.computeProjectionMatrixFOV(45.0, aspect, 0.02, 20.0)
    else:
        if view == "top":
            lo, hi = _scene_bounds(world)
            span = float(np.max(hi[:2] - lo[:2]))
            view_m = p.computeViewMatrixFromYawPitchRoll(((lo + hi) / 2).tolist(), 1.3 * span + 1.0, 0, -89.9, 0, 2)
        else:
            centre, distance, yaw, pitch = overview_framing(world)
            view_m = p.computeViewMatrixFromYawPitchRoll(centre, distance, yaw, pitch, 0, 2)
        proj = p.computeProjectionMatrixFOV(50.0, aspect, 0.05, 50.0)
    return Camera(tuple(view_m), tuple(proj))


def render_world(
    world: World, width: int = 960, height: int = 720, view: str = "overview", cam: Camera | None = None
) -> np.ndarray:
    """An RGB image (height, width, 3) uint8 of the world, rendered headless (TinyRenderer); ``cam``: a fixed
    camera (default: ``view`` framed on the world as it is now)."""
    c = cam if cam is not None else camera(world, width, height, view)
    _, _, rgba, _, _ = p.getCameraImage(
        width, height, c.view, c.projection, renderer=p.ER_TINY_RENDERER, shadow=1,
        lightDirection=[1.0, 0.6, 2.0], physicsClientId=world.client,
    )
    return np.asarray(rgba, dtype=np.uint8).reshape(height, width, 4)[:, :, :3]


def render_scene_png(
    scene: Scene, path: str | Path, width: int = 960, height: int = 720, view: str = "overview"
) -> Path:
    """Build ``scene``, render it and write a PNG; returns the path."""
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    world = build_world(scene)
    try:
        rgb = render_world(world, width, height, view)
    finally:
        world.close()
    if not cv2.imwrite(str(out), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
        raise RlgpError(f"could not write {out}")
    log.info("wrote %s (%dx%d, %s view)", out, width, height, view)
    return out
