"""Long sequences' keyframes chunk by chunk: the cut points, the hand-over between chunks (start
configuration, objects where the last chunk left them), the doomed prefix of a failing chunk, and the
search dropping every candidate that shares a doomed prefix."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.keyframe_chunks import HAND_EMPTY_AFTER, ChunkedKeyframes, chunks
from rlgp_exec.planning.nlp.keyframes import KeyframeResult
from rlgp_exec.planning.symbolic import best_first, goal_lower_bound, ground_scene
from rlgp_exec.scene.generate import sorting_scene
from rlgp_exec.scene.types import pose_matrix

NAMES = ("pick", "place", "stack", "take_knob", "open_drawer", "close_drawer", "drop")


@given(st.lists(st.sampled_from(NAMES), max_size=30), st.integers(1, 6))
def test_chunks_cut_only_where_the_hand_is_empty(names, size):
    actions = [Action(n, f"o{i}") for i, n in enumerate(names)]
    parts = chunks(actions, size)
    assert [a for p in parts for a in p] == actions
    for p in parts[:-1]:
        assert p[-1].name in HAND_EMPTY_AFTER
    for p in parts:
        free = [i for i, a in enumerate(p[:-1]) if a.name in HAND_EMPTY_AFTER]
        # longer than size only when no earlier cut point would have kept it within size
        assert len(p) <= size or not free or max(free) + 1 < size


def _fake_solver(calls, fail_at=None):
    """A keyframe solver that moves each picked object 0.1 m in x and records what it was given."""

    def solve(scene, q_start, part, tilt, cache):
        calls.append((q_start.copy(), {o.name: o.pose for o in scene.objects}, [str(a) for a in part]))
        poses = {o.name: pose_matrix(o.pose) for o in scene.objects}
        frames, after = [], []
        for a in part:
            if a.name == "place":
                poses = {**poses, a.obj: pose_matrix((0.1, 0.0, 0.0, 0.0)) @ poses[a.obj]}
            frames.append(q_start + len(calls) + len(frames))
            after.append(dict(poses))
        ok = fail_at is None or len(calls) != fail_at
        return KeyframeResult(ok, np.array(frames), tuple(after), tuple({} for _ in part), 1.0, 0.0 if ok else 1.0,
                              1.0, "ok" if ok else "constraints violated")

    return solve


def test_each_chunk_starts_where_the_last_left_the_robot_and_the_objects():
    scene = sorting_scene("hsr", 3, 0)
    names = [o.name for o in scene.objects]
    actions = [Action(k, n, "tray" if k == "place" else None) for n in names for k in ("pick", "place")]
    calls: list = []
    q0 = np.zeros(4)
    result = ChunkedKeyframes(size=2)(_fake_solver(calls), scene, q0, actions)
    assert result.ok and len(calls) == 3 and result.keyframes.shape == (6, 4)
    assert np.allclose(calls[1][0], result.keyframes[1]) and np.allclose(calls[2][0], result.keyframes[3])
    x0 = {o.name: o.pose[0] for o in scene.objects}
    assert np.isclose(calls[1][1][names[0]][0], x0[names[0]] + 0.1)  # moved by chunk 1, seen by chunk 2
    assert np.isclose(calls[1][1][names[1]][0], x0[names[1]])
    assert result.cost == 3.0 and len(result.object_poses) == 6


def test_a_failing_chunk_dooms_its_prefix_and_the_last_one_dooms_nothing():
    scene = sorting_scene("hsr", 3, 0)
    actions = [Action(k, o.name, "tray" if k == "place" else None) for o in scene.objects for k in ("pick", "place")]
    r = ChunkedKeyframes(size=2)(_fake_solver([], fail_at=2), scene, np.zeros(4), actions)
    assert not r.ok and r.doomed == 4 and r.reason.startswith("chunk 2/3 (actions 3-4)")
    r = ChunkedKeyframes(size=2)(_fake_solver([], fail_at=3), scene, np.zeros(4), actions)
    assert not r.ok and r.doomed == 0  # the whole sequence: the search moves on to the next candidate anyway


def test_the_search_drops_every_candidate_with_a_forbidden_prefix():
    problem = ground_scene(sorting_scene("hsr", 3, 0))
    it = best_first(problem, heuristic=goal_lower_bound(problem), max_visits=6)
    first = next(it)
    it.forbid(first.actions[:2])
    later = [next(it) for _ in range(5)]
    assert all(p.actions[:2] != first.actions[:2] for p in later)
    assert all(problem.reaches_goal(p.actions) for p in later)
