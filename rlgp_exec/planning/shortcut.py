"""Shortcutting a guided path: the reachability graph's waypoints wander (every node has its own base
pose and yaw); straight configuration-space edges between non-neighbouring waypoints, where they are
collision-free, make the path shorter and far faster to execute on a base limited to 0.05 m/s^2."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from rlgp_exec.robot.model import FloatArray

__all__ = ["shortcut"]


def shortcut(path: FloatArray, edge_collides: Callable[[FloatArray, FloatArray], bool]) -> FloatArray:
    """Greedy shortcut of ``path`` (n, nq): from each kept waypoint jump to the farthest one reachable by
    a collision-free straight edge (``edge_collides(a, b)`` checks the whole edge). Endpoints are kept;
    a path of two waypoints or fewer is returned as is. At most n^2 / 2 edge checks."""
    path = np.asarray(path, float)
    n = len(path)
    if n <= 2:
        return path
    keep, i = [0], 0
    while i < n - 1:
        for j in range(n - 1, i, -1):
            if j == i + 1 or not edge_collides(path[i], path[j]):
                keep.append(j)
                i = j
                break
    return path[keep]
