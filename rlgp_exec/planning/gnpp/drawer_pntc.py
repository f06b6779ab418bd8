"""The drawer part of GNPP's PNTC model (``pntc``): the factors Pi maps the drawer actions' partial states
to, for ``take_knob``, ``open_drawer`` / ``close_drawer`` and ``drop`` (the shared domain's schemas).

A drawer's opening is not a variable: the logic state fixes it ((closed c): 0, (open c): the drawer's
travel; GNPP starts with every drawer closed), so each factor's function is the one for that opening
and the key names it. An object in a drawer (``(in o c)``) has its pose ``x`` (4,) = [x, y, z, yaw] in
the drawer's frame (``DrawerView.T_world_drawer``), as a held object's is in the tool's: ``Equal``
carries it unchanged while the drawer opens or closes, i.e. it moves with the drawer.

=============  ===========================================  ===============================================
factor         partial states                               constraint
=============  ===========================================  ===============================================
Knob(m,c,d)    {(knob-free c)} -> {(holding-knob m c), d}   q_{t+1}^m's hand on c's knob at opening d
Drive(m,c,a)   {(holding-knob m c), d} -> {(knob-free c)}   q_{t+1}^m = q_t^m with the base moved along
                                                            the drawer's axis by the change of opening
Drop(o,m,c)    {(holding m o)} -> {(in o c)}                the held object upright over c's open drawer,
                                                            x_{t+1}^o where it lands (below the release)
InDrawer(o,c)  {(holding m o)} -> {(in o c)}                x_{t+1}^o on the drawer's floor, inside
ColFix(m,tag)  {not (initial-state), openings, knob}        arm m clear of the fixtures and the drawers at
                                                            their openings (not the one its hand is on)
ColAO/ColHO    {not (initial-state), (in o c), (open c)}    arm / hand m clear of o in c's open drawer
(m,o,c)
ColOO(a,b,c)   {(in a c), (in b c)}                         two objects in one drawer apart (a drop gap)
=============  ===========================================  ===============================================

An object in a closed drawer is inside the carcass (``ColFix``): no arm factor. While the hand holds a
knob ``EqualBase`` is not applied to the drive: the base moves with the drawer.
"""

from __future__ import annotations

import itertools
from collections.abc import Sequence

from rlgp_exec.planning.gnpp.factor import INITIAL, Factor, Var
from rlgp_exec.planning.gnpp.factor import partial_state as ps
from rlgp_exec.planning.symbolic.model import Atom, SymbolicState
from rlgp_exec.planning.symbolic.reformulate import PartialState

__all__ = [
    "DRAWER_KINDS",
    "cabinets",
    "colfix",
    "drawer_state_factors",
    "drawer_transition_factors",
    "drives",
    "in_drawer",
    "opening_atom",
]

DRAWER_KINDS = ("Knob", "Drive", "Drop", "InDrawer")


def cabinets(s: SymbolicState) -> list[str]:
    """The drawer cabinets of the state (those with an (open c) or (closed c) atom), sorted."""
    return sorted({a[1] for a in s if a[0] in ("open", "closed")})


def opening_atom(s: SymbolicState, c: str) -> Atom:
    """(open c) or (closed c), whichever holds in ``s``."""
    return ("open", c) if ("open", c) in s else ("closed", c)


def in_drawer(s: SymbolicState) -> dict[str, str]:
    """Object -> the cabinet whose drawer it is in."""
    return {a[1]: a[2] for a in s if a[0] == "in"}


def knob_of(s: SymbolicState, arm: str) -> str | None:
    return next((a[2] for a in s if a[0] == "holding-knob" and a[1] == arm), None)


def drives(arm: str, s: SymbolicState, s2: SymbolicState) -> bool:
    """Does ``arm`` open or close a drawer from s to s2 (it holds a knob in s, not in s2)?"""
    c = knob_of(s, arm)
    return c is not None and knob_of(s2, arm) is None


def colfix(t: int, s: SymbolicState, prev: SymbolicState | None, arm: str) -> Factor:
    """ColFix(m, tag) at t: the fixtures with every drawer at its opening in ``s``; the tag names them ("c:open",
    "c:closed", "+knob" where the hand is on c's knob: it holds it, or has just let it go at the end of a
    drive), and its partial states state exactly that."""
    knob, let_go = knob_of(s, arm), prev is not None and drives(arm, prev, s)
    if let_go and prev is not None:
        knob = knob_of(prev, arm)
    pos: list[Atom] = []
    neg: list[Atom] = [INITIAL]
    before: list[Atom] = []  # at t - 1
    before_neg: list[Atom] = []
    tags = []
    for c in cabinets(s):
        at = opening_atom(s, c)
        pos.append(at)
        grip = ("holding-knob", arm, c)
        if c != knob:
            neg.append(grip)
            if t > 0:
                before_neg.append(grip)
        elif let_go:
            before.append(grip)
            neg.append(grip)
        else:
            pos.append(grip)
        tags.append(f"{c}:{at[0]}{'+knob' if c == knob else ''}")
    partial: tuple[tuple[int, PartialState], ...] = ((t, ps(pos, neg)),)
    if before or before_neg:
        partial = ((t - 1, ps(before, before_neg)), *partial)
    return Factor(("ColFix", arm, ",".join(tags)), (Var("q", arm, t),), partial)


def drawer_state_factors(t: int, s: SymbolicState, prev: SymbolicState | None, arms: Sequence[str]) -> list[Factor]:
    """The arms clear of the objects in open drawers, and objects in one drawer apart, at t."""
    out: list[Factor] = []
    inside = in_drawer(s)
    if INITIAL not in s:
        for o, c in sorted(inside.items()):
            if ("open", c) not in s:
                continue
            for m in arms:
                where = [("in", o, c), ("open", c)]
                out.append(Factor(("ColAO", m, o, c), (Var("q", m, t), Var("x", o, t)),
                                  ((t, ps(where, [INITIAL])),)))
                if t > 0 and prev is not None and in_drawer(prev).get(o) == c:  # not just dropped
                    out.append(Factor(("ColHO", m, o, c), (Var("q", m, t), Var("x", o, t)),
                                      ((t, ps(where, [INITIAL])),)))
    for a, b in itertools.combinations(sorted(inside), 2):
        c = inside[a]
        if inside[b] == c:
            out.append(Factor(("ColOO", a, b, c), (Var("x", a, t), Var("x", b, t)),
                              ((t, ps([("in", a, c), ("in", b, c)])),)))
    return out


def drawer_transition_factors(
    t: int, s: SymbolicState, s2: SymbolicState, arms: Sequence[str], holder: dict[str, str]
) -> list[Factor]:
    """The drawer actions' switch factors from s to s2 (``holder``: object -> the arm holding it in s)."""
    out: list[Factor] = []
    for m in arms:
        c, c2 = knob_of(s, m), knob_of(s2, m)
        if c is None and c2 is not None:  # take_knob
            at = opening_atom(s2, c2)
            fs = ((t, ps([("knob-free", c2)])), (t + 1, ps([("holding-knob", m, c2), at])))
            out.append(Factor(("Knob", m, c2, at[0]), (Var("q", m, t + 1),), fs))
        elif c is not None and c2 is None:  # open_drawer / close_drawer
            before, after = opening_atom(s, c), opening_atom(s2, c)
            what = "open" if after[0] == "open" else "close"
            fs = ((t, ps([("holding-knob", m, c), before])), (t + 1, ps([("knob-free", c), after])))
            out.append(Factor(("Drive", m, c, what), (Var("q", m, t), Var("q", m, t + 1)), fs))
    for o, cab in sorted(in_drawer(s2).items()):
        arm = holder.get(o)
        if arm is None or ("in", o, cab) in s:
            continue
        m, c = arm, cab
        fs = ((t, ps([("holding", m, o)])), (t + 1, ps([("in", o, c)])))
        out.append(Factor(("Drop", o, m, c), (Var("q", m, t + 1), Var("x", o, t + 1), Var("x", o, t)), fs))
        out.append(Factor(("InDrawer", o, c), (Var("x", o, t + 1),), fs))
    return out
