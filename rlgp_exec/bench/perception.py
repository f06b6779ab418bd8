"""``rlgp-exec bench perception``: pose accuracy against distance, detection speed, false positives.

Rendered head-camera images (HSR camera model, 640x480) of the tagged objects of ``sorting_hsr`` from
random viewpoints at 0.4-1.5 m (elevation 45-85 deg, any azimuth, the tag anywhere in the central
part of the image), with mild pixel noise. Every detector available runs on the same images. Tag-free
images (the same world without tag textures, plus noise and blank frames) measure false positives.
"""

from __future__ import annotations

import logging
import math
import os
import platform
import time
from typing import Any

import numpy as np
import pybullet as p

from rlgp_exec.errors import RlgpError
from rlgp_exec.perception.camera import camera_for_robot
from rlgp_exec.perception.detector import DETECTORS, TagDetector
from rlgp_exec.perception.pipeline import Perception
from rlgp_exec.perception.pose import rotation_angle
from rlgp_exec.perception.registry import TagRegistry
from rlgp_exec.perception.rendered_camera import ImageEffects, render_camera
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.shipped import shipped_scene_path
from rlgp_exec.world.pybullet_world import build_world

__all__ = ["DISTANCES", "look_at", "run_perception_bench"]

log = logging.getLogger(__name__)

DISTANCES = (0.4, 0.6, 0.8, 1.0, 1.25, 1.5)
SCENE = shipped_scene_path("sorting_hsr")


def look_at(eye: np.ndarray, target: np.ndarray) -> np.ndarray:
    """T_world_camera (4, 4), optical frame (z forward, y down), looking from ``eye`` at ``target``."""
    z = target - eye
    z = z / np.linalg.norm(z)
    x = np.cross(z, [0.0, 0.0, 1.0])
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-6 else np.array([1.0, 0.0, 0.0])
    T = np.eye(4)
    T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, np.cross(z, x), z, eye
    return T


def _available() -> list[str]:
    out = []
    for name in DETECTORS:
        try:
            TagDetector(name)
            out.append(name)
        except RlgpError:
            pass
    return out


def _median(xs: list[float]) -> float | None:
    return float(np.median(xs)) if xs else None


def run_perception_bench(seed: int = 0, views_per_distance: int = 12, negatives: int = 20) -> dict:
    rng = np.random.default_rng(seed)
    scene = load_scene(SCENE)
    cam = camera_for_robot("hsr")
    registry = TagRegistry.from_scene(scene)
    world = build_world(scene)
    detectors = {name: TagDetector(name) for name in _available()}
    runs: list[dict] = []
    try:
        names = [o.name for o in scene.objects if o.tag is not None]
        for d in DISTANCES:
            log.info("%s: %d views at %.2f m (%s)", scene.name, views_per_distance, d, ", ".join(detectors))
            for k in range(views_per_distance):
                name = names[k % len(names)]
                tag = world.tag_pose(name)[:3, 3]
                elev, az = math.radians(rng.uniform(45, 85)), rng.uniform(0, 2 * math.pi)
                eye = tag + d * np.array([math.cos(elev) * math.cos(az), math.cos(elev) * math.sin(az), math.sin(elev)])
                # aim off the tag so it lands anywhere in the central 60 % of the image
                off = np.array(
                    [rng.uniform(-0.3, 0.3) * cam.width / cam.fx, rng.uniform(-0.3, 0.3) * cam.height / cam.fy]
                )
                T0 = look_at(eye, tag)
                T = look_at(eye, tag + d * (off[0] * T0[:3, 0] + off[1] * T0[:3, 1]))
                img = render_camera(world, cam, T, ImageEffects(noise_std=2.0, seed=int(rng.integers(1 << 30))))
                truth = world.object_pose(name)
                for det_name, det in detectors.items():
                    per = Perception(registry, cam, det)
                    rep = per.process(img, T, 0.0)
                    obs = [o for o in rep.observations if o.object == name]
                    run = {
                        "detector": det_name,
                        "distance_m": d,
                        "object": name,
                        "detected": bool(obs),
                        "detect_ms": rep.detect_ms,
                    }
                    if obs:
                        Tw = obs[0].T_world_object
                        run["pos_err_mm"] = float(np.linalg.norm(Tw[:3, 3] - truth[:3, 3]) * 1e3)
                        run["rot_err_deg"] = math.degrees(rotation_angle(truth[:3, :3].T @ Tw[:3, :3]))
                    runs.append(run)
        # false positives: the same world without tag textures, random views; plus noise and blank frames
        plain = build_world(scene, client=p.connect(p.DIRECT), tags=False)
        fp_images = []
        try:
            for _ in range(negatives):
                eye = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-2.0, 0.0), rng.uniform(0.9, 1.6)])
                target = np.array([rng.uniform(-0.8, 0.8), rng.uniform(-0.4, 0.4), 0.7])
                fp_images.append(render_camera(plain, cam, look_at(eye, target)))
        finally:
            plain.close()
        fp_images += [rng.integers(0, 256, (cam.height, cam.width, 3), dtype=np.uint8) for _ in range(negatives // 2)]
        fp_images += [np.zeros((cam.height, cam.width, 3), np.uint8)]
        fp = {name: sum(len(det.detect(im).detections) for im in fp_images) for name, det in detectors.items()}
        # detection speed on a typical 640x480 frame, repeated
        frame = render_camera(world, cam, look_at(np.array([0.0, -1.2, 1.4]), np.array([0.0, 0.0, 0.75])))
        speed = {}
        for name, det in detectors.items():
            ts = []
            for _ in range(30):
                t0 = time.perf_counter()
                det.detect(frame)
                ts.append((time.perf_counter() - t0) * 1e3)
            speed[name] = float(np.median(ts))
    finally:
        world.close()

    per_detector: dict[str, dict[str, Any]] = {}
    for name in detectors:
        rs = [r for r in runs if r["detector"] == name]
        ok = [r for r in rs if r["detected"]]
        by_d = {
            f"{d:g}": {
                "detection_rate": sum(r["detected"] for r in rs if r["distance_m"] == d) / views_per_distance,
                "pos_err_mm_median": _median([r["pos_err_mm"] for r in ok if r["distance_m"] == d]),
                "rot_err_deg_median": _median([r["rot_err_deg"] for r in ok if r["distance_m"] == d]),
            }
            for d in DISTANCES
        }
        per_detector[name] = {
            "detection_rate": len(ok) / max(len(rs), 1),
            "pos_err_mm_median": _median([r["pos_err_mm"] for r in ok]),
            "rot_err_deg_median": _median([r["rot_err_deg"] for r in ok]),
            "detect_ms_median": speed[name],
            "false_positives": fp[name],
            "by_distance": by_d,
        }
    main = per_detector["opencv"]
    return {
        "task": "perception",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "camera": {"width": cam.width, "height": cam.height, "hfov_deg": cam.hfov_deg},
        "runs": runs,
        "summary": {
            "detector": "opencv",
            "pos_err_mm_median": main["pos_err_mm_median"],
            "pos_err_mm_median_at_0.6m": main["by_distance"]["0.6"]["pos_err_mm_median"],
            "pos_err_mm_median_at_1.5m": main["by_distance"]["1.5"]["pos_err_mm_median"],
            "rot_err_deg_median": main["rot_err_deg_median"],
            "rot_err_deg_median_at_0.6m": main["by_distance"]["0.6"]["rot_err_deg_median"],
            "detect_ms_median": main["detect_ms_median"],
            "detection_rate": main["detection_rate"],
            "false_positive_rate": main["false_positives"] / len(fp_images),
            "negative_images": len(fp_images),
            "detectors": per_detector,
        },
    }
