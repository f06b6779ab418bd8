"""Conflicts known before any NLP: what no arm reaches from the start base (``capabilities.start_reach_gaps``,
a sound bound) forbidden while the base is still there.

An object beyond every arm's reach from the start base cannot be held before the base has moved (its
first pick is where the scene put it), and a goal target beyond it cannot receive the object then:
``(holding a o)`` and ``(on o s)`` are forbidden together with ``(base-at-start m)`` (``pntc.at_start``) for
every arm a on m's base. GNPP would learn each of them from a failed graph-NLP (one loop iteration, some
tens of NLPs, each); stated up front, the logic's first plans already drive the base. A base kept at
its start (``plan_gnpp(drive_base=False)``) with a gap is infeasible at once, the gap its reason.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from rlgp_exec.planning.capabilities import ReachGap
from rlgp_exec.planning.gnpp.pntc import at_start
from rlgp_exec.planning.symbolic.model import Atom
from rlgp_exec.planning.symbolic.reformulate import ForbiddenSequence, PartialState

__all__ = ["reach_priors"]


def reach_priors(
    gaps: Sequence[ReachGap], arms: Sequence[str], base_arm: str, riders: Mapping[str, str], init: frozenset[Atom]
) -> list[tuple[ForbiddenSequence, ReachGap]]:
    """One forbidden partial state per gap and arm riding ``base_arm``'s base (``arms``: all the robot's,
    the base is shared), each with the gap that justifies it; none for a target the object rests on at
    the start (``init``)."""
    flag = at_start(base_arm)
    on_base = [a for a in arms if a == base_arm or riders.get(a) == base_arm]
    out = []
    for g in gaps:
        if g.target is None:
            facts = [("holding", a, g.obj) for a in on_base]
        elif ("on", g.obj, g.target) in init:
            continue
        else:
            facts = [("on", g.obj, g.target)]
        out += [(ForbiddenSequence((PartialState(frozenset({f, flag})),)), g) for f in facts]
    return out
