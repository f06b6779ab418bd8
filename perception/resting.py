"""A resting object's tag observation moved along the viewing ray onto its support.

A tag's pose from one image is good across the line of sight and poor along it: a small, far tag's
depth error sinks a resting object into its table or lifts it off. An object that rests on a surface has
a known height, the surface's plus half its own; moving the observed tag along the ray from the camera
until the object is at that height corrects x, y and z together. :class:`RestingSupports` does that to
each observation before it is fused, on the surfaces an object may rest on (fixture and cabinet tops,
the tops of the other objects where they are estimated), and leaves an observation alone when no surface
is near enough in height (the object is lifted or the surface is not known) or the ray runs nearly level.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace

import numpy as np

from rlgp_exec.perception.camera import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Surface, support_surfaces

__all__ = ["RAY_MIN_SLOPE", "REST_GAP_MAX_M", "RestingSupports"]

REST_GAP_MAX_M = 0.04  # [m] an object's bottom within this of a surface's height is taken as resting on it
SHIFT_MAX_SIGMA = 3.0  # a correction along the ray longer than this x the observation's error figure is not noise
RAY_MIN_SLOPE = 0.2  # a ray rising or falling less than this per metre fixes no height (a grazing view)


class RestingSupports:
    """The surfaces of ``scene`` that objects rest on, and the ray correction onto them."""

    def __init__(self, scene: Scene) -> None:
        fixtures = {fx.name for fx in scene.fixtures}
        bare = replace(scene, objects=())
        # drawer floors are out of the head camera's sight: what is in a drawer is kept by the hand
        self._fixed = [s for s in support_surfaces(bare, openings={}) if s.name in fixtures]
        self._sizes = {o.name: o.size for o in scene.objects}
        self.corrected = 0  # observations moved onto a support

    def surfaces(self, name: str, others: Mapping[str, FloatArray]) -> list[Surface]:
        """Fixture tops, and the tops of the objects in ``others`` (name -> T_world_object) but ``name``."""
        out = list(self._fixed)
        for other, T in others.items():
            size = self._sizes.get(other)
            if other == name or size is None:
                continue
            top = np.array(T, dtype=float)
            top[:3, 3] += top[:3, 2] * size[2] / 2
            out.append(Surface(other, top, (size[0], size[1])))
        return out

    def onto_support(
        self,
        name: str,
        T_world_object: FloatArray,
        p_world_tag: FloatArray,
        p_world_camera: FloatArray,
        pos_std_m: float,
        others: Mapping[str, FloatArray],
    ) -> FloatArray:
        """``T_world_object`` (4, 4), observed through a tag at ``p_world_tag`` (3,) from a camera at
        ``p_world_camera`` (3,), moved along that ray so that ``name`` rests on the nearest surface in
        height under it; unchanged when none is within REST_GAP_MAX_M, the shift would exceed
        SHIFT_MAX_SIGMA x ``pos_std_m`` [m], or the ray is nearly level."""
        size = self._sizes.get(name)
        if size is None:
            return T_world_object
        ray = np.asarray(p_world_tag, float) - np.asarray(p_world_camera, float)
        length = float(np.linalg.norm(ray))
        if length <= 0.0 or abs(ray[2]) < RAY_MIN_SLOPE * length:
            return T_world_object
        z_obs = float(T_world_object[2, 3])
        best: tuple[float, FloatArray] | None = None
        for s in self.surfaces(name, others):
            z_rest = s.z + size[2] / 2
            gap = abs(z_rest - z_obs)
            if gap > REST_GAP_MAX_M:
                continue
            shift = ray * ((z_rest - z_obs) / ray[2])
            if float(np.linalg.norm(shift)) > SHIFT_MAX_SIGMA * pos_std_m:
                continue
            if not s.contains(T_world_object[:2, 3] + shift[:2]):
                continue
            if best is None or gap < best[0]:
                best = (gap, shift)
        if best is None:
            return T_world_object
        T = np.array(T_world_object, dtype=float)
        T[:3, 3] += best[1]
        self.corrected += 1
        return T
