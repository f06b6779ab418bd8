"""Seeded randomisation of object poses on their supports, and the scene's geometry hash."""

from __future__ import annotations

import hashlib
import json
from dataclasses import replace

import numpy as np

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.geometry import Box, boxes_overlap, object_box, pose_of, support_surfaces
from rlgp_exec.scene.types import Scene, SceneObject, pose_matrix
from rlgp_exec.scene.validate import _static_boxes, footprint_radius

__all__ = ["MAX_TRIES", "randomize", "scene_hash"]

MAX_TRIES = 2000
CLEARANCE = 0.01  # [m] kept between freshly placed objects


def _inflated(b: Box, margin: float) -> Box:
    return Box(b.name, (b.size[0] + 2 * margin, b.size[1] + 2 * margin, b.size[2]), b.T, b.color)


def randomize(scene: Scene, seed: int, clearance: float = CLEARANCE) -> Scene:
    """A copy of ``scene`` with every object that has a ``random`` table placed anew.

    Positions are drawn in the support's frame, rejection-sampled until the object's footprint lies on
    its support and clears fixtures and the other objects (the ones drawn before it included) by
    ``clearance`` [m].
    Same seed, same scene.
    """
    rng = np.random.default_rng(seed)
    surfaces = {s.name: s for s in support_surfaces(scene)}
    statics = _static_boxes(scene)
    fixed = {o.name: object_box(o) for o in scene.objects if o.random is None}
    placed: dict[str, SceneObject] = {}
    for o in scene.objects:
        if o.random is None:
            continue
        surf = surfaces[o.support]
        r = footprint_radius(o)
        T_local_nominal = np.linalg.inv(surf.T) @ o.T
        for _ in range(MAX_TRIES):
            lx, ly, _, lyaw = pose_of(T_local_nominal)
            lx = rng.uniform(*o.random.x) if o.random.x else lx
            ly = rng.uniform(*o.random.y) if o.random.y else ly
            lyaw = rng.uniform(*o.random.yaw) if o.random.yaw else lyaw
            T = surf.T @ pose_matrix((lx, ly, o.size[2] / 2, lyaw))
            if not surf.contains(T[:2, 3], margin=r):
                continue
            cand = replace(o, pose=pose_of(T))
            box = _inflated(object_box(cand), clearance)
            others = [*fixed.values(), *(object_box(p) for p in placed.values())]
            if any(boxes_overlap(box, s) for s in statics) or any(boxes_overlap(box, b) for b in others):
                continue
            placed[o.name] = cand
            break
        else:
            raise SceneError(scene.source, f"[[object]] '{o.name}'.random",
                             f"could not place the object on {o.support!r} in {MAX_TRIES} tries (seed {seed})")
    objects = tuple(placed.get(o.name, o) for o in scene.objects)
    return replace(scene, objects=objects)


def scene_hash(scene: Scene) -> str:
    """sha256 of the robot and the static geometry (fixtures, regions), not the movable objects."""
    canon = {
        "robot": scene.robot.name,
        "fixtures": [[f.name, f.shape, f.kind, [round(v, 6) for v in (*f.size, *f.pose)],
                      None if f.drawer is None else [f.drawer.travel, f.drawer.knob_height, f.drawer.height]]
                     for f in sorted(scene.fixtures, key=lambda f: f.name)],
        "regions": [[r.name, r.on, [round(v, 6) for v in (*r.size, *r.offset)]]
                    for r in sorted(scene.regions, key=lambda r: r.name)],
    }
    return hashlib.sha256(json.dumps(canon, sort_keys=True).encode()).hexdigest()
