"""Repairing a GNPP plan whose replay collides on the way between keyframes.

The graph-NLP keeps the arms clear of everything at the keyframes and on the vertical lines into and out
of them (``ColHO``); the moves between them (``motion.Transit``: an arm from where the plan left it to above
its next keyframe, or an idle arm home) are straight joint motions, re-optimised by ``gnpp.trajectory``
when it can. A move that still sweeps an arm through the table or a block in the replay (the upper arm
over the table's edge on the way to a pick) used to cost the whole plan: it was blocked, and the logic
planner asked for another. Here each such move is checked with the reachability graph's exact edge check
(``WorldChecker.edge_collides``: the objects where they rest, the held one attached) and, if it collides,
planned again by OMPL on the arm's joints (``reach.ompl_plan.plan_ompl``, every segment of its path passing
that check). The keyframes stay; the replay then judges the repaired plan as any other.
"""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping, Sequence
from dataclasses import replace

import numpy as np

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.motion import Transit, place, world_checker
from rlgp_exec.planning.validate import Phase, Validation, validate_with_fallbacks
from rlgp_exec.reach.ompl_plan import plan_ompl
from rlgp_exec.scene import Scene

__all__ = ["OMPL_TIMEOUT_S", "collided_phases", "repair_rounds", "repair_transits"]

log = logging.getLogger(__name__)
OMPL_TIMEOUT_S = 1.0  # [s] OMPL's time per move planned again
_PHASE = re.compile(r"phase (\d+):")


def collided_phases(collisions: Sequence[str]) -> set[int]:
    """The phase indices the replay's ``collisions`` name (``"phase k: ..."``)."""
    return {int(m.group(1)) for c in collisions if (m := _PHASE.match(c))}


def repair_transits(
    lib: FactorLib, phases: Sequence[Phase], transits: Sequence[Transit], collisions: Sequence[str]
) -> list[Phase] | None:
    """The phases with every move (``transits``, rows of the straight ``phases``) of a phase named in the
    replay's ``collisions`` that fails the exact edge check replaced by an OMPL path; None if there is none
    to repair (no move of those phases collides) or OMPL finds no certified path for one."""
    bad = collided_phases(collisions)
    out, repaired = list(phases), 0
    checkers: dict = {}  # arm -> its WorldChecker, built once (a PyBullet world each)
    try:
        # last rows first: a phase's earlier moves keep their row indices when a later one grows
        for t in sorted((t for t in transits if t.phase in bad), key=lambda t: (t.phase, t.row), reverse=True):
            path = out[t.phase].path
            a, b = path[t.row], path[t.row + 1]
            idx = lib.arm_index(t.arm)
            joints = idx[3:] if lib.mobile else idx  # a mobile arm's base stands still on these moves
            checker = checkers.get(t.arm)
            if checker is None:
                checker = checkers[t.arm] = world_checker(lib, t.arm, t.resting, t.held)
            else:
                place(checker, lib, t.resting, t.held)
            if not checker.edge_collides(a, b):
                continue
            sub = plan_ompl(checker, joints, a, b, a[:2], a[:2], timeout=OMPL_TIMEOUT_S)
            if sub is None:
                log.info("phase %d: no certified path for %s's move%s", t.phase, t.arm, " home" if t.home else "")
                return None
            out[t.phase] = replace(out[t.phase], path=np.vstack([path[: t.row], sub, path[t.row + 2 :]]))
            repaired += 1
            log.info("phase %d: %s's move%s planned again by OMPL (%d rows)", t.phase, t.arm,
                     " home" if t.home else "", len(sub))
    finally:
        for checker in checkers.values():
            checker.close()
    return out if repaired else None


def repair_rounds(
    scene: Scene, lib: FactorLib, phases: Sequence[Phase], transits: Sequence[Transit], validation: Validation,
    fallbacks: Mapping[int, Phase], kept: set[int], label: str = "gnpp",
) -> tuple[Validation, list[Phase], set[int]]:
    """The replay's (validation, phases, kept: the phases still on their optimised paths) after repairing
    (``repair_transits``) what it found colliding, round after round: the replay stops at the first
    collision, so one round repairs one phase. It stops when the replay passes, when no move of the colliding
    phase can be repaired, or when a phase repaired before collides again (its OMPL rows are no longer the
    ones the transits index): at most one round per phase. ``fallbacks``: the originals of the optimised
    phases (``validate_with_fallbacks``)."""
    out, done = list(phases), set[int]()
    while not validation.collision_free:
        bad = collided_phases(validation.collisions)
        if not bad or bad & done:
            break
        repaired = repair_transits(lib, out, transits, validation.collisions)
        if repaired is None:
            break
        done |= bad
        log.info("%s: the replay collided (%s); again with moves OMPL planned", label, validation.collisions[0])
        validation, out, kept = validate_with_fallbacks(scene, repaired, {k: fallbacks[k] for k in kept})
    return validation, out, kept
