"""The ``rlgp-exec perceive`` workflows: a scene in simulation, or image files from a real camera."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from rlgp_exec.perception.camera import CameraIntrinsics, PerceptionError, camera_for_robot
from rlgp_exec.perception.detector import TagDetector
from rlgp_exec.perception.look_around import look_around
from rlgp_exec.perception.pipeline import Perception, scene_from_estimates
from rlgp_exec.perception.pose import estimate_tag_pose, rotation_angle
from rlgp_exec.perception.registry import TagRegistry
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import support_surfaces
from rlgp_exec.scene.types import pose_matrix

__all__ = [
    "SimPerception",
    "perceive_image",
    "perceive_scene",
    "perturb_objects",
    "perturbed_poses",
    "perturbed_scene",
]

log = logging.getLogger(__name__)


def perturbed_poses(scene: Scene, magnitude_m: float, seed: int) -> dict[str, np.ndarray]:
    """T_world_object of each tagged object moved by up to ``magnitude_m`` in x/y and 0.3 rad in yaw
    away from the scene file (the file is then wrong, as it is on a real robot). An object with a
    ``random`` table stays inside its x/y ranges (in its support's frame): those ranges are where the
    scene says the object can be (e.g. tower_pr2's back row, kept within one arm's reach)."""
    rng = np.random.default_rng(seed)
    surfaces = {s.name: s for s in support_surfaces(scene)}
    truth = {}
    for obj in scene.objects:
        if obj.tag is None:
            continue
        x, y, z, yaw = obj.pose
        d = rng.uniform(-1.0, 1.0, 2) * magnitude_m
        T = pose_matrix((x + d[0], y + d[1], z, yaw + rng.uniform(-0.3, 0.3)))
        surf = surfaces.get(obj.support)
        if obj.random is not None and surf is not None:
            T_local = np.linalg.inv(surf.T) @ T
            for k, rng_k in enumerate((obj.random.x, obj.random.y)):
                if rng_k is not None:
                    T_local[k, 3] = float(np.clip(T_local[k, 3], *rng_k))
            T = surf.T @ T_local
        truth[obj.name] = T
    return truth


def perturbed_scene(scene: Scene, magnitude_m: float, seed: int) -> Scene:
    """The world as it really is when the file is off by :func:`perturbed_poses`."""
    truth = perturbed_poses(scene, magnitude_m, seed)
    objects = tuple(
        replace(o, pose=(float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), math.atan2(T[1, 0], T[0, 0])))
        if (T := truth.get(o.name)) is not None
        else o
        for o in scene.objects
    )
    return replace(scene, objects=objects)


def perturb_objects(world, scene: Scene, magnitude_m: float, seed: int) -> dict[str, np.ndarray]:
    """Move the tagged objects of the simulated world to :func:`perturbed_poses`; returns the truth."""
    truth = perturbed_poses(scene, magnitude_m, seed)
    for name, T in truth.items():
        world.set_object_pose(name, T)
    return truth


@dataclass(frozen=True)
class SimPerception:
    """What perceiving a scene in simulation found: per object, the error against the simulated truth."""

    errors_mm: dict[str, float]
    yaw_errors_deg: dict[str, float]
    missing: frozenset[str]
    views: int
    scene: Scene  # the scene with perceived poses
    uncertain: frozenset[str]


def perceive_scene(
    scene: Scene,
    *,
    perturb_m: float = 0.0,
    seed: int = 0,
    noise_std: float = 2.0,
    detector: str = "opencv",
    max_views: int = 30,
) -> SimPerception:
    """Build ``scene`` in PyBullet, optionally move its objects away from the file's poses, look around
    with the robot's head camera and compare the perceived poses with the simulated truth."""
    # local: perception.rendered_camera and world.pybullet_world bring PyBullet
    from rlgp_exec.perception.rendered_camera import ImageEffects, SimCapture
    from rlgp_exec.world.pybullet_world import build_world

    world = build_world(scene)
    try:
        truth = (
            perturb_objects(world, scene, perturb_m, seed)
            if perturb_m > 0
            else {o.name: world.object_pose(o.name) for o in scene.objects if o.tag is not None}
        )
        cam = camera_for_robot(scene.robot.name)
        per = Perception(TagRegistry.from_scene(scene), cam, TagDetector(detector))
        capture = SimCapture(world, cam, ImageEffects(noise_std=noise_std, seed=seed))
        q0 = world.robot.get_q()
        res = look_around(
            per,
            world.robot_model,
            q0,
            scene,
            sorted(truth),
            capture,
            max_views=max_views,
            feasible=lambda q: not world.robot.in_collision(q),
        )
        upd = scene_from_estimates(scene, per.tracker, capture.stamp)
        errs, yaw = {}, {}
        for name in truth:
            est = per.tracker.estimate(name)
            if est is None:
                continue
            T = est.T_world_object
            errs[name] = float(np.linalg.norm(T[:3, 3] - truth[name][:3, 3]) * 1e3)
            yaw[name] = math.degrees(rotation_angle(truth[name][:3, :3].T @ T[:3, :3]))
        missing = frozenset(n for n in truth if per.tracker.estimate(n) is None)  # never seen at all
        return SimPerception(errs, yaw, missing, len(res.views), upd.scene, upd.uncertain)
    finally:
        world.close()


def perceive_image(
    path: str | Path, intrinsics: CameraIntrinsics, tag_size: float, detector: str = "opencv"
) -> list[dict]:
    """Tags in an image file: id, T_camera_tag, reprojection error; a bad file raises PerceptionError."""
    p = Path(path)
    if not p.is_file():
        raise PerceptionError(f"image file {p} does not exist")
    img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
    if img is None:
        raise PerceptionError(f"cannot read image {p}: not a PNG/JPEG or corrupted")
    h, w = img.shape
    if (w, h) != (intrinsics.width, intrinsics.height):
        raise PerceptionError(f"image {p} is {w}x{h}, the intrinsics are for {intrinsics.width}x{intrinsics.height}")
    if not (tag_size > 0):
        raise PerceptionError(f"tag size must be > 0 m, got {tag_size}")
    result = TagDetector(detector).detect(img)
    out = []
    for det in result.detections:
        pose, why = estimate_tag_pose(det, tag_size, intrinsics)
        out.append(
            {
                "tag_id": det.tag_id,
                "side_px": det.side_px,
                "ok": pose is not None,
                "reason": why,
                "T_camera_tag": None if pose is None else pose.T_camera_tag.tolist(),
                "reproj_px": None if pose is None else pose.reproj_px,
            }
        )
    out += [{"tag_id": i, "ok": False, "reason": why} for i, why in result.rejected]
    return out
