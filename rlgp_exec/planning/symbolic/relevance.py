"""Detour pruning: operators that can only take an object away from its goal surface, removed before search.

An object whose goal is ``(on o s)`` with ``s`` a surface (a fixture's top or a region with room for several
objects, so placing there needs nothing but the object in the hand) never needs to be put anywhere else:
whenever the hand can put it down elsewhere it can put it on ``s``, and no precondition of the domain asks
for an object to be on a particular surface except picking it from there again. So ``place``/``stack``/``drop``
of ``o`` onto anything but ``s``, and ``pick`` of ``o`` from ``s``, are detours: every plan that uses them has
a plan without them that is no longer. Objects without a goal (blockers), goals onto slots or other objects
(towers, Hanoi: a block may have to wait elsewhere) and goals into drawers (the hand must be free to open
one) keep every operator. Removing the detours is what keeps sorting N objects from exploring every
temporary placement of every object.
"""

from __future__ import annotations

import logging
from dataclasses import replace

from rlgp_exec.planning.actions import PUT_DOWN, Kind
from rlgp_exec.planning.symbolic.model import GroundProblem, Operator

__all__ = ["PUT_DOWN", "SURFACE_TYPES", "without_detours"]

log = logging.getLogger(__name__)

#: the types a ``place`` needs nothing of (any number of objects fit)
SURFACE_TYPES = ("surface", "cabinet")
#: the actions that leave an object somewhere: (object, support) are their arguments 1 and 2


def without_detours(problem: GroundProblem) -> GroundProblem:
    """``problem`` without the detour operators described in the module docstring (the same problem if none)."""
    types = dict(problem.objects)
    target = {
        g[1]: g[2] for g in problem.goal if g[0] == "on" and len(g) == 3 and types.get(g[2]) in SURFACE_TYPES
    }
    if not target:
        return problem

    def detour(op: Operator) -> bool:
        a = op.action
        if len(a.args) < 3 or a.args[1] not in target:
            return False
        goal_support = target[a.args[1]]
        if a.name in PUT_DOWN:
            return a.args[2] != goal_support
        return a.name == Kind.PICK and a.args[2] == goal_support

    kept = tuple(op for op in problem.operators if not detour(op))
    log.debug("%s: %d detour operators removed (%d kept)", problem.name, len(problem.operators) - len(kept), len(kept))
    return replace(problem, operators=kept)
