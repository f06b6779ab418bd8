"""Place: the held object is set down on a region or a fixture (its top face), released just above it."""

from __future__ import annotations

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions.kind import ActionKind, Kind
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene

__all__ = ["PLACE", "target_surface"]

PLACE = ActionKind(Kind.PLACE, "surface", True, True, True)


def target_surface(scene: Scene, target: str) -> tuple[FloatArray, tuple[float, float], float]:
    """(T of the target rectangle's centre (4, 4), its half extents, its surface height [m])."""
    for r in scene.regions:
        if r.name == target:
            fx = scene.fixture(r.on)
            T = fx.T.copy()
            T[:3, 3] = (fx.T @ np.array([r.offset[0], r.offset[1], fx.size[2] / 2, 1.0]))[:3]
            return T, (r.size[0] / 2, r.size[1] / 2), float(T[2, 3])
    try:
        fx = scene.fixture(target)
    except KeyError:
        valid = sorted([r.name for r in scene.regions] + [f.name for f in scene.fixtures])
        raise RlgpError(f"place target {target!r} is not a region or fixture; valid: {valid}") from None
    T = fx.T.copy()
    T[2, 3] += fx.size[2] / 2
    return T, (fx.size[0] / 2, fx.size[1] / 2), float(T[2, 3])
