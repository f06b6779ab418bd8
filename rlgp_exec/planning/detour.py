"""Base detours round fixture footprints: the shortest polyline in the world plane along which a disc
of a given radius (the base's enclosing circle) keeps off every footprint rectangle.

A visibility graph over points round the rectangles' corners (three per corner, on a circle a little
wider than the radius, so that the chords between them keep the radius off the corner): a proposal
for a transport that drives round a table, not a certificate (the robot's configurations and motions
along it are checked exactly by the caller).
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Sequence

import numpy as np

from rlgp_exec.robot.model import FloatArray

__all__ = ["Footprint", "detour", "rect_distance", "segment_distance", "segment_hits"]

Footprint = tuple[FloatArray, FloatArray]  # (T (3, 3) or (4, 4) world pose, size (2,) or (3,) [m])
CORNER_SLACK = 1e-3  # [m] the points round a corner keep the radius plus this much off it
TOUCH = 1e-6  # [m] a segment may come this much closer than the radius without counting as a hit


def _frame(T: FloatArray) -> tuple[FloatArray, FloatArray]:
    """(R (2, 2), centre (2,)) of a footprint's planar pose."""
    T = np.asarray(T, float)
    return T[:2, :2], T[:2, -1]


def rect_distance(xy: FloatArray, T: FloatArray, size: FloatArray) -> float:
    """Distance [m] from the point xy (2,) to the footprint rectangle (0 inside it)."""
    R, c = _frame(T)
    local = R.T @ (np.asarray(xy, float) - c)
    return float(np.linalg.norm(np.maximum(np.abs(local) - np.asarray(size[:2], float) / 2, 0.0)))


def _point_segment(x: FloatArray, p: FloatArray, q: FloatArray) -> float:
    """Distance [m] from the point x to the segment p -> q."""
    d = q - p
    n = float(d @ d)
    t = 0.0 if n < 1e-18 else min(1.0, max(0.0, float((x - p) @ d) / n))
    return float(np.linalg.norm(x - (p + t * d)))


def segment_distance(p: FloatArray, q: FloatArray, T: FloatArray, size: FloatArray) -> float:
    """Distance [m] from the segment p -> q (world plane) to the footprint rectangle (0 when they meet):
    for two disjoint convex sets in the plane, the nearest pair has a vertex of one of them."""
    R, c = _frame(T)
    a, b = R.T @ (np.asarray(p, float) - c), R.T @ (np.asarray(q, float) - c)
    h = np.asarray(size[:2], float) / 2
    lo, hi, d = 0.0, 1.0, b - a  # Liang-Barsky: does the segment enter the closed rectangle?
    for k in range(2):
        if abs(d[k]) < 1e-12:
            if abs(a[k]) > h[k]:
                lo, hi = 1.0, 0.0
            continue
        t1, t2 = (-h[k] - a[k]) / d[k], (h[k] - a[k]) / d[k]
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
    if lo <= hi:
        return 0.0
    ends = min(float(np.linalg.norm(np.maximum(np.abs(x) - h, 0.0))) for x in (a, b))
    return min(ends, *(_point_segment(v, a, b) for v in _corners(np.eye(3), h)))


def segment_hits(p: FloatArray, q: FloatArray, T: FloatArray, size: FloatArray, radius: float) -> bool:
    """True when a disc of ``radius`` [m] moving along p -> q would overlap the footprint rectangle
    (touching it, within TOUCH, does not count)."""
    return segment_distance(p, q, T, size) < radius - TOUCH


def _corners(T: FloatArray, half: FloatArray) -> FloatArray:
    """(4, 2) world corners of the rectangle of half extents ``half`` at pose T."""
    R, c = _frame(T)
    signs = np.array([[1, 1], [-1, 1], [-1, -1], [1, -1]], float)
    return c + (signs * np.asarray(half, float)) @ R.T


def _round_corners(T: FloatArray, size: FloatArray, radius: float) -> FloatArray:
    """(12, 2) world points round the rectangle's corners: per corner, three on the circle of
    radius ``radius / cos(22.5 deg)`` (plus CORNER_SLACK) about it, square to either side and on its
    diagonal, so that the chords between them keep ``radius`` off the corner."""
    R, c = _frame(T)
    h = np.asarray(size[:2], float) / 2
    rho = (radius + CORNER_SLACK) / math.cos(math.pi / 8)
    out = []
    for sx, sy in ((1, 1), (-1, 1), (-1, -1), (1, -1)):
        corner = np.array([sx * h[0], sy * h[1]])
        for u in ((sx, 0.0), (sx * math.sqrt(0.5), sy * math.sqrt(0.5)), (0.0, sy)):
            out.append(c + R @ (corner + rho * np.asarray(u)))
    return np.array(out)


def detour(start: FloatArray, goal: FloatArray, rects: Sequence[Footprint], radius: float) -> FloatArray | None:
    """The shortest polyline (n, 2) [m] from ``start`` to ``goal`` whose segments keep a disc of
    ``radius`` [m] off every rectangle in ``rects`` (its corners bent round the rectangles' corners);
    an end closer than ``radius`` to the rectangles has its own segment keep as far off them as the
    end itself is. None when an end is inside a rectangle or no such polyline exists."""
    start, goal = np.asarray(start, float)[:2], np.asarray(goal, float)[:2]
    rects = [(np.asarray(T, float), np.asarray(size, float)) for T, size in rects]
    near = [min([radius, *(rect_distance(x, T, size) for T, size in rects)]) for x in (start, goal)]
    if min(near) <= 0.0:
        return None
    nodes = [start, goal]
    for T, size in rects:
        for x in _round_corners(T, size, radius):
            if all(rect_distance(x, T2, s2) >= radius for T2, s2 in rects):
                nodes.append(x)

    def visible(i: int, j: int) -> bool:
        r = min([radius, *(near[k] for k in (i, j) if k < 2)])
        return not any(segment_hits(nodes[i], nodes[j], T, size, r) for T, size in rects)

    # Dijkstra from the start (node 0) to the goal (node 1), edges tested when first relaxed
    dist, prev, done = {0: 0.0}, {0: -1}, set()
    heap = [(0.0, 0)]
    while heap:
        d, i = heapq.heappop(heap)
        if i in done:
            continue
        done.add(i)
        if i == 1:
            out = [1]
            while prev[out[-1]] >= 0:
                out.append(prev[out[-1]])
            return np.array([nodes[k] for k in reversed(out)])
        for j in range(len(nodes)):
            if j in done:
                continue
            nd = d + math.dist(nodes[i], nodes[j])
            if nd < dist.get(j, math.inf) and visible(i, j):
                dist[j], prev[j] = nd, i
                heapq.heappush(heap, (nd, j))
    return None
