"""Long action sequences' keyframes, solved chunk by chunk.

One keyframe NLP over every action of a 20-action sequence is large (its clearance rows grow with
the actions times the objects) and IPOPT often ends infeasible in it, while consecutive pick-place
pairs far apart hardly constrain each other. :class:`ChunkedKeyframes` cuts a sequence where the hand
is empty into chunks of at most ``size`` actions and solves them in order, each from the last
keyframe of the one before, with the objects and drawers where that one left them; a failing chunk
dooms the prefix up to its end, whatever follows (``KeyframeResult.doomed``), so the symbolic search
can drop every candidate that shares it. Sequences of at most ``JOINT_ACTIONS`` are solved jointly
(by the caller): the shipped tasks keep their single solve.
"""

from __future__ import annotations

import logging
import math
from collections import OrderedDict
from collections.abc import Callable, Sequence
from dataclasses import replace

import numpy as np

from rlgp_exec.planning.actions import DRIVES, PUT_DOWN
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.keyframes import KeyframeResult
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene.types import Scene, StartState

__all__ = ["CHUNK_ACTIONS", "HAND_EMPTY_AFTER", "JOINT_ACTIONS", "ChunkedKeyframes", "chunks"]

log = logging.getLogger(__name__)

JOINT_ACTIONS = 8  # sequences up to the longest shipped task's length are solved jointly
CHUNK_ACTIONS = 2  # longer ones a pick and its put-down at a time: a failing pair is then named exactly
#: actions after which the hand is empty (a chunk may end there)
HAND_EMPTY_AFTER = (*PUT_DOWN, *DRIVES)
_CACHES = 8  # chunk NLPs kept for a retry from the same start (another tilt)

#: ``solve(scene, q_start, actions, max_tilt, cache)``: one keyframe NLP (``solve_keyframes`` with the caller's
#: options)
ChunkSolver = Callable[[Scene, FloatArray, list[Action], float, dict], KeyframeResult]


def chunks(actions: Sequence[Action], size: int = CHUNK_ACTIONS) -> list[list[Action]]:
    """``actions`` cut after hand-empty actions into runs of at most ``size`` (longer only where the hand is
    never empty for ``size`` actions in a row)."""
    out: list[list[Action]] = []
    start, free = 0, -1  # the current chunk's first action; the last hand-empty cut point in it
    for i, a in enumerate(actions):
        if a.name in HAND_EMPTY_AFTER:
            free = i
        if i - start + 1 >= size and free >= start:
            out.append(list(actions[start : free + 1]))
            start = free + 1
    if start < len(actions):
        out.append(list(actions[start:]))
    return out


def _pose(T: FloatArray) -> tuple[float, float, float, float]:
    """(x, y, z, yaw) of an upright T_world_obj."""
    return (float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), float(math.atan2(T[1, 0], T[0, 0])))


class ChunkedKeyframes:
    """Keyframes of a sequence by :func:`chunks`; keeps each chunk's NLP for a retry from the same start."""

    def __init__(self, size: int = CHUNK_ACTIONS) -> None:
        self.size = size
        self._caches: OrderedDict[bytes, dict] = OrderedDict()

    def _cache(self, k: int, scene: Scene, q_start: FloatArray, actions: list[Action]) -> dict:
        key = repr((k, [str(a) for a in actions], [o.pose for o in scene.objects], scene.start)).encode()
        key += np.asarray(q_start, float).tobytes()
        cache = self._caches.pop(key, None) or {}
        self._caches[key] = cache
        while len(self._caches) > _CACHES:
            self._caches.popitem(last=False)
        return cache

    def __call__(
        self, solve: ChunkSolver, scene: Scene, q_start: FloatArray, actions: list[Action],
        tilts: Sequence[float] = (0.0,),
    ) -> KeyframeResult:
        """Every chunk of ``actions`` by ``solve``, in order, each at the first of ``tilts`` (grasps' largest
        lean [rad]) that solves it; the first chunk that no tilt solves ends it."""
        parts = chunks(actions, self.size)
        results: list[KeyframeResult] = []
        done = 0
        for k, part in enumerate(parts):
            cache = self._cache(k, scene, q_start, part)
            for tilt in tilts:  # a chunk leans its grasps only if it must
                r = solve(scene, q_start, part, tilt, cache)
                if r.ok:
                    break
            results.append(r)
            log.info("keyframes: chunk %d/%d (%s) %s", k + 1, len(parts), " ".join(str(a) for a in part),
                     "solved" if r.ok else f"failed: {r.reason}")
            if not r.ok:
                if len(parts) > 1:  # the chunks before were solved from the same start: this prefix is doomed
                    r = replace(r, doomed=done + len(part) if k + 1 < len(parts) else 0,
                                reason=f"chunk {k + 1}/{len(parts)} (actions {done + 1}-{done + len(part)}): "
                                       f"{r.reason}")
                return _joined(results[:-1], r, q_start.size)
            done += len(part)
            q_start = r.keyframes[-1]
            after = r.object_poses[-1]
            scene = replace(
                scene.with_object_poses({n: _pose(T) for n, T in after.items()}),
                start=StartState(openings=tuple(sorted((c, o) for c, o in r.openings[-1].items() if o > 0.0))),
            )
        return _joined(results[:-1], results[-1], q_start.size)


def _joined(done: list[KeyframeResult], last: KeyframeResult, nq: int) -> KeyframeResult:
    """The chunks' results as one: keyframes, poses and openings in order; costs and times summed."""
    if not done:
        return last
    parts = [*done, last]
    frames = [r.keyframes for r in parts if r.keyframes.size]
    return KeyframeResult(
        last.ok,
        np.vstack(frames) if frames else np.zeros((0, nq)),
        tuple(p for r in parts for p in r.object_poses),
        tuple(o for r in parts for o in r.openings),
        float(sum(r.cost for r in parts)),
        max(r.violation for r in parts),
        float(sum(r.solve_ms for r in parts)),
        last.reason,
        last.doomed,
    )
