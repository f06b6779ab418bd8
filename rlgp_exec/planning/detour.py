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


_Rect = tuple[float, float, float, float, float, float, float, float]  # centre, R (row-major), half extents


def _rect(T: FloatArray, size: FloatArray) -> _Rect:
    """A footprint as plain floats (the visibility tests run ~10^3 times a detour: no numpy per test)."""
    R, c = _frame(T)
    return (float(c[0]), float(c[1]), float(R[0, 0]), float(R[0, 1]), float(R[1, 0]), float(R[1, 1]),
            float(size[0]) / 2, float(size[1]) / 2)


def _local(r: _Rect, x: float, y: float) -> tuple[float, float]:
    """The point (x, y) [m] in the footprint's frame (R^T (p - c))."""
    dx, dy = x - r[0], y - r[1]
    return r[2] * dx + r[4] * dy, r[3] * dx + r[5] * dy


def _enters(ax: float, ay: float, bx: float, by: float, hx: float, hy: float) -> bool:
    """The segment a -> b (local frame) meets the closed box |x| <= hx, |y| <= hy (Liang-Barsky)."""
    lo, hi = 0.0, 1.0
    for a, d, h in ((ax, bx - ax, hx), (ay, by - ay, hy)):
        if abs(d) < 1e-12:
            if abs(a) > h:
                return False
            continue
        t1, t2 = (-h - a) / d, (h - a) / d
        lo, hi = max(lo, min(t1, t2)), min(hi, max(t1, t2))
        if lo > hi:
            return False
    return True


def _box_point(x: float, y: float, hx: float, hy: float) -> float:
    """Distance [m] from (x, y) to the box |x| <= hx, |y| <= hy (local frame; 0 inside)."""
    return math.hypot(max(abs(x) - hx, 0.0), max(abs(y) - hy, 0.0))


def _point_segment(x: float, y: float, ax: float, ay: float, bx: float, by: float) -> float:
    """Distance [m] from the point (x, y) to the segment a -> b."""
    dx, dy = bx - ax, by - ay
    n = dx * dx + dy * dy
    t = 0.0 if n < 1e-18 else min(1.0, max(0.0, ((x - ax) * dx + (y - ay) * dy) / n))
    return math.hypot(x - ax - t * dx, y - ay - t * dy)


def _segment_distance(r: _Rect, p: Sequence[float], q: Sequence[float]) -> float:
    """``segment_distance`` on a footprint of plain floats."""
    (ax, ay), (bx, by) = _local(r, p[0], p[1]), _local(r, q[0], q[1])
    hx, hy = r[6], r[7]
    if _enters(ax, ay, bx, by, hx, hy):
        return 0.0
    ends = min(_box_point(ax, ay, hx, hy), _box_point(bx, by, hx, hy))
    return min(ends, *(_point_segment(sx * hx, sy * hy, ax, ay, bx, by) for sx in (-1, 1) for sy in (-1, 1)))


def _hits(r: _Rect, p: Sequence[float], q: Sequence[float], radius: float) -> bool:
    """``segment_hits`` on a footprint of plain floats; a segment missing the footprint's square grown by
    ``radius`` (which holds the rounded one) misses at once."""
    (ax, ay), (bx, by) = _local(r, p[0], p[1]), _local(r, q[0], q[1])
    if not _enters(ax, ay, bx, by, r[6] + radius, r[7] + radius):
        return False
    return _segment_distance(r, p, q) < radius - TOUCH


def rect_distance(xy: FloatArray, T: FloatArray, size: FloatArray) -> float:
    """Distance [m] from the point xy (2,) to the footprint rectangle (0 inside it)."""
    r = _rect(T, size)
    return _box_point(*_local(r, float(xy[0]), float(xy[1])), r[6], r[7])


def segment_distance(p: FloatArray, q: FloatArray, T: FloatArray, size: FloatArray) -> float:
    """Distance [m] from the segment p -> q (world plane) to the footprint rectangle (0 when they meet):
    for two disjoint convex sets in the plane, the nearest pair has a vertex of one of them."""
    return _segment_distance(_rect(T, size), [float(v) for v in p[:2]], [float(v) for v in q[:2]])


def segment_hits(p: FloatArray, q: FloatArray, T: FloatArray, size: FloatArray, radius: float) -> bool:
    """True when a disc of ``radius`` [m] moving along p -> q would overlap the footprint rectangle
    (touching it, within TOUCH, does not count)."""
    return _hits(_rect(T, size), [float(v) for v in p[:2]], [float(v) for v in q[:2]], radius)


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
    flat = [_rect(T, size) for T, size in rects]
    pts = [(float(x[0]), float(x[1])) for x in nodes]

    def visible(i: int, j: int) -> bool:
        r = min([radius, *(near[k] for k in (i, j) if k < 2)])
        return not any(_hits(f, pts[i], pts[j], r) for f in flat)

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
            nd = d + math.dist(pts[i], pts[j])
            if nd < dist.get(j, math.inf) and visible(i, j):
                dist[j], prev[j] = nd, i
                heapq.heappush(heap, (nd, j))
    return None
