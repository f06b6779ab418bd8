"""Base detours round fixture footprints (planning.detour) and the transport that drives them."""

from __future__ import annotations

import itertools
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from rlgp_exec.planning.detour import TOUCH, detour, rect_distance, segment_distance

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"


def _pose(x: float, y: float, yaw: float) -> np.ndarray:
    T = np.eye(4)
    T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
    T[:2, 3] = x, y
    return T


rects_st = st.lists(
    st.tuples(
        st.floats(-2.0, 2.0), st.floats(-2.0, 2.0), st.floats(-math.pi, math.pi),
        st.floats(0.2, 1.6), st.floats(0.2, 1.6),
    ).map(lambda r: (_pose(r[0], r[1], r[2]), np.array([r[3], r[4], 0.7]))),
    min_size=1, max_size=3,
)
point_st = st.tuples(st.floats(-4.0, 4.0), st.floats(-4.0, 4.0)).map(np.array)


@settings(max_examples=300, deadline=None)
@given(point_st, point_st, st.tuples(st.floats(-2, 2), st.floats(-2, 2), st.floats(-math.pi, math.pi),
                                     st.floats(0.1, 1.5), st.floats(0.1, 1.5)))
def test_segment_distance_is_the_least_distance_of_its_points(p, q, r):
    T, size = _pose(r[0], r[1], r[2]), np.array([r[3], r[4]])
    d = segment_distance(p, q, T, size)
    samples = [rect_distance(p + s * (q - p), T, size) for s in np.linspace(0.0, 1.0, 401)]
    step = float(np.linalg.norm(q - p)) / 400
    assert d <= min(samples) + 1e-9
    assert d >= min(samples) - step - 1e-9


@settings(max_examples=300, deadline=None)
@given(point_st, point_st, rects_st, st.floats(0.2, 0.6))
def test_a_detour_keeps_the_disc_off_every_footprint_and_joins_the_ends(start, goal, rects, radius):
    path = detour(start, goal, rects, radius)
    near = [min([radius, *(rect_distance(x, T, s) for T, s in rects)]) for x in (start, goal)]
    if path is None:
        return
    assert np.allclose(path[0], start) and np.allclose(path[-1], goal)
    n = len(path) - 1
    for k, (p, q) in enumerate(itertools.pairwise(path)):
        keep = min([radius, *([near[0]] if k == 0 else []), *([near[1]] if k == n - 1 else [])])
        for T, size in rects:
            assert segment_distance(p, q, T, size) >= keep - TOUCH - 1e-9


@settings(max_examples=200, deadline=None)
@given(point_st, point_st, rects_st.map(lambda r: r[:1]), st.floats(0.2, 0.6))
def test_round_one_footprint_there_is_always_a_detour_and_a_clear_line_is_kept(start, goal, rects, radius):
    """A single (convex) footprint never blocks the way between two ends that stand off it; where the
    straight line is clear the detour is that line."""
    T, size = rects[0]
    if min(rect_distance(x, T, size) for x in (start, goal)) <= 1e-3:
        return
    path = detour(start, goal, rects, radius)
    assert path is not None
    near = min([radius, *(rect_distance(x, T, size) for x in (start, goal))])
    if segment_distance(start, goal, T, size) >= near:
        assert len(path) == 2


def test_an_end_inside_a_footprint_has_no_detour():
    table = (np.eye(4), np.array([1.2, 0.6, 0.72]))
    assert detour(np.array([0.0, 0.0]), np.array([0.0, 2.0]), [table], 0.5) is None


@pytest.fixture(scope="module")
def pick_place():
    from rlgp_exec.planning.sequence import SequenceGeometry
    from rlgp_exec.scene import load_scene

    geo = SequenceGeometry(load_scene(SCENES / "pick_place_pr2.toml"))
    yield geo
    geo.close()


@pytest.mark.parametrize("held", [False, True])
def test_a_transport_to_the_far_side_of_a_table_drives_round_it(pick_place, held):
    """The start posture in front of the table and the same posture across it, facing it: every
    straight drive crosses the table, so the transport drives round its end; each of its motions
    (the held box too) passes the exact check."""
    geo = pick_place
    q_near = geo.q0.copy()
    q_far = q_near.copy()
    q_far[:3] = q_near[0], -q_near[1], q_near[2] + math.pi
    if held:
        T_tool_obj = np.eye(4)
        T_tool_obj[2, 3] = 0.06
        geo.checker.attach(np.array([0.05, 0.05, 0.10]), T_tool_obj)
    try:
        assert not geo.checker(q_near) and not geo.checker(q_far)
        assert geo.checker.edge_collides(q_near, q_far)
        path = geo.moves.transport(q_near, q_far)
        assert path is not None
        assert np.allclose(path[0], q_near) and np.allclose(path[-1], q_far)
        assert not any(geo.checker(q) for q in path)
        assert not any(geo.checker.edge_collides(u, v) for u, v in itertools.pairwise(path))
        table = geo.scene.fixtures[0]
        assert max(abs(q[0]) for q in path) > table.size[0] / 2  # round the table's end
    finally:
        geo.checker.detach()
