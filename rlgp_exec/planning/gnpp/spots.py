"""Where an object's guess starts on a surface: apart from the objects already resting there."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

__all__ = ["free_spot"]

FloatArray = NDArray[np.float64]


def free_spot(
    T_world_surface: FloatArray, half: FloatArray, size: Sequence[float], others: list[FloatArray], n: int = 7
) -> FloatArray:
    """The xy (2,) on an n x n grid over the surface (inset by the object's footprint, as ``Place``)
    farthest from the other resting objects' centres (the surface's centre if none): objects placed
    on one region must not start at the same point (a signed distance has no gradient there)."""
    margin = max(size[0], size[1]) / 2
    ax, ay = (max(float(h) - margin, 0.0) for h in half[:2])
    grid = np.array([(x, y) for x in np.linspace(-ax, ax, n) for y in np.linspace(-ay, ay, n)])
    pts = T_world_surface[:2, 3] + grid @ T_world_surface[:2, :2].T
    if not others:
        return T_world_surface[:2, 3].copy()
    d = np.min(np.linalg.norm(pts[:, None, :] - np.asarray(others)[None, :, :], axis=2), axis=1)
    return pts[int(np.argmax(d))].copy()
