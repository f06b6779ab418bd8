"""Rendered camera images: what a robot's head camera sees in a PyBullet world.

The image is rendered with exactly the pinhole model of :class:`rlgp_exec.perception.camera.CameraIntrinsics`
(so a detector's PnP sees the geometry PyBullet drew), optionally degraded by Gaussian pixel noise,
blur and a change of light direction, as a real camera sees it.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import cv2
import numpy as np
import pybullet as p

from rlgp_exec.perception.camera import CameraIntrinsics, FloatArray
from rlgp_exec.world.pybullet_world import World

__all__ = ["ImageEffects", "SimCapture", "camera_pose", "hide_floor", "render_camera"]

_GL_FROM_OPTICAL = np.diag([1.0, -1.0, -1.0, 1.0])  # GL eye frame: x right, y up, looking along -z
#: PyBullet's TinyRenderer draws the image shifted by this much [px] against an exact OpenGL viewport
#: (measured: corners of rendered tags vs their projections, over random views; see tests/test_perception.py)
TINY_RENDERER_SHIFT_PX = (1.0, 0.0)
_FAR_DEPTH = 1.0 - 1e-6  # depth-buffer value of a pixel nothing was drawn on (the far plane)


def hide_floor(world: World) -> tuple[int, int, int]:
    """Make the floor invisible and return its shaded colour, to paint where nothing else is drawn.

    The floor is one 40 m box whose triangles cover most of a head camera's image, and TinyRenderer
    rasterises every triangle over its whole screen bounding box: it takes two thirds of a frame. Under a
    directional light without shadows a flat floor has one shade, so painting the empty pixels that
    colour draws the same picture (above the horizon too: the sky is floor-coloured)."""
    small = CameraIntrinsics.from_hfov(16, 16, 20.0)
    T = np.eye(4)
    T[:3, :3] = np.diag([1.0, -1.0, -1.0])  # looking straight down
    T[:3, 3] = [19.0, 19.0, 1.0]  # the floor's corner, away from any scene
    rgb = render_camera(world, small, T)
    colour = tuple(int(c) for c in np.median(rgb.reshape(-1, 3), axis=0))
    p.changeVisualShape(world.floor, -1, rgbaColor=[1, 1, 1, 0], physicsClientId=world.client)
    return colour[0], colour[1], colour[2]


@dataclass(frozen=True)
class ImageEffects:
    """Degradations: pixel noise std [grey levels], Gaussian blur sigma [px], light direction (world)."""

    noise_std: float = 0.0
    blur_sigma: float = 0.0
    light_direction: tuple[float, float, float] = (1.0, 0.6, 2.0)
    seed: int = 0


def camera_pose(world: World) -> FloatArray:
    """T_world_camera (4, 4) of the robot's head camera (optical frame) at its current configuration."""
    model = world.robot_model
    return model.fk(world.robot.get_q(), model.config.frames["camera"])


def _hide_housing(world: World) -> list[tuple[int, list[float]]]:
    """Make the robot's camera housing links invisible; their (link, rgba) to restore."""
    links = {world.robot.link_index[n] for n in world.robot_model.config.camera_housing}
    if not links:
        return []
    hidden = []
    for shape in p.getVisualShapeData(world.robot.id, physicsClientId=world.client):
        if shape[1] in links:
            hidden.append((shape[1], list(shape[7])))
            p.changeVisualShape(world.robot.id, shape[1], rgbaColor=[1, 1, 1, 0], physicsClientId=world.client)
    return hidden


def render_camera(
    world: World,
    intrinsics: CameraIntrinsics,
    T_world_camera: FloatArray | None = None,
    effects: ImageEffects = ImageEffects(),
    background: tuple[int, int, int] | None = None,
) -> np.ndarray:
    """An RGB image (H, W, 3) uint8 from ``T_world_camera`` (default: the robot's head camera).
    ``background``: the colour of pixels where nothing was drawn (see :func:`hide_floor`)."""
    T = camera_pose(world) if T_world_camera is None else np.asarray(T_world_camera, float)
    view = np.linalg.inv(T @ _GL_FROM_OPTICAL)
    du, dv = TINY_RENDERER_SHIFT_PX
    render_model = replace(intrinsics, cx=intrinsics.cx - du, cy=intrinsics.cy - dv)
    hidden = _hide_housing(world) if T_world_camera is None else []
    try:
        _, _, rgba, depth, _ = p.getCameraImage(
            intrinsics.width,
            intrinsics.height,
            view.T.reshape(-1).tolist(),
            render_model.gl_projection(),
            renderer=p.ER_TINY_RENDERER,
            shadow=0,
            lightDirection=list(effects.light_direction),
            flags=p.ER_NO_SEGMENTATION_MASK,
            physicsClientId=world.client,
        )
    finally:
        for link, rgba_link in hidden:
            p.changeVisualShape(world.robot.id, link, rgbaColor=rgba_link, physicsClientId=world.client)
    img = np.asarray(rgba, dtype=np.uint8).reshape(intrinsics.height, intrinsics.width, 4)[:, :, :3].copy()
    if background is not None:
        img[np.asarray(depth).reshape(intrinsics.height, intrinsics.width) >= _FAR_DEPTH] = background
    if effects.blur_sigma > 0.0:
        img = np.asarray(cv2.GaussianBlur(img, (0, 0), effects.blur_sigma), dtype=np.uint8)
    if effects.noise_std > 0.0:
        rng = np.random.default_rng(effects.seed)
        noisy = img.astype(np.float32) + rng.normal(0.0, effects.noise_std, img.shape).astype(np.float32)
        img = np.clip(noisy, 0, 255).astype(np.uint8)
    return img


class SimCapture:
    """Take pictures in simulation: put the robot at ``q``, render its head camera, and return
    (image, T_world_camera from FK, stamp [s]) — what a robot's camera driver and TF give."""

    def __init__(
        self,
        world: World,
        intrinsics: CameraIntrinsics,
        effects: ImageEffects = ImageEffects(),
        period: float = 1.0 / 30.0,
    ) -> None:
        self.world, self.intrinsics, self.effects, self.period = world, intrinsics, effects, period
        self.stamp = 0.0
        self.frames = 0

    def __call__(self, q: FloatArray) -> tuple[np.ndarray, FloatArray, float]:
        self.world.robot.set_q(q)
        self.stamp += self.period
        self.frames += 1
        fx = replace(self.effects, seed=self.effects.seed + self.frames)
        return render_camera(self.world, self.intrinsics, None, fx), camera_pose(self.world), self.stamp
