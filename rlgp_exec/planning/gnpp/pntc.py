"""The PNTC model (GNPP paper, Sec. III): logic states, continuous variables, and the mapping Pi from
consecutive partial states to constraint factors.

Logic: the ground STRIPS task of ``symbolic`` (pick / place / stack and the drawer actions take_knob,
open_drawer / close_drawer and drop, for every arm; their factors: ``drawer_pntc``), read as SAS+-like
variables: ``parent(o)`` = the support an object rests on, the cabinet whose drawer it is in, or the arm
holding it, ``gripper(m)`` =
free or the held object. Two flag atoms are added so that Pi is time-invariant: ``(at-init o)``
(o rests where the scene put it; deleted by every pick of o — the paper's ``parent = o.init``) and
``(initial-state)`` (deleted by every action; the arms are at their start configuration).

A mobile arm (an arm on a mobile base: the paper's Field scenario) gets the paper's two move operators
(``add_moves``): ``(start-move m)`` adds ``(moving m)``, ``(end-move m)`` deletes it, and pick / place /
stack by m require ``(not (moving m))``; ``(base-at-start m)`` holds until m's first start-move (what the
start base cannot reach is forbidden with it up front: ``priors``). While m is moving its base may
change; otherwise ``EqualBase`` holds it between time steps, so a base pose that cannot reach two
keyframes is a conflict like any other, and the logic learns to move the base between them. Further
arms on the same base (the PR2's second arm: a "rider" of m) have no move operators of their own:
their actions also require ``(not (moving m))``, and ``SameBase`` ties the base in their variable to m's at every step.

Continuous variables per time step t (the state s_t, i.e. after the t-th action): ``q``/arm (7,; a
mobile arm: base x, y, yaw and its joints) and ``x``/object (4,) (see ``geometry``). Pi (each factor
records the partial states that generated it, by time index, for tracing a conflict back to the logic):

=========  ======================================  ===========================================
factor     partial states                          constraint
=========  ======================================  ===========================================
RefQ(m)    {(initial-state)} at t                  q_t^m = start
Ref(o)     {(at-init o)} at t                      x_t^o = the scene pose
Kin(o,m)   {(on o s)} -> {(holding m o)} or back   tool(q_{t+1}^m) x^o_held = x^o_world
Grasp(o)   {(on o s)} -> {(holding m o)}           x_{t+1}^o a grasp from above between the fingers
Place(o,s) {(holding m o)} -> {(on o s)}           x_{t+1}^o on surface/slot s (inside, resting)
On(o,p)    {(holding m o)} -> {(on o p)}           x_{t+1}^o resting on object x_{t+1}^p
Equal(o)   parent unchanged t -> t+1               x_t^o = x_{t+1}^o
EqualBase  {not (moving m)} at t and t+1           base of q_t^m = base of q_{t+1}^m (mobile arm m)
SameBase   {not (initial-state)} at t              base of q_t^r = base of q_t^m (r rides m's base)
ColFix(m)  {not (initial-state)} at t              arm m clear of the fixtures
ColAA      {not (initial-state)} at t              the two arms clear of each other
ColAO(m,o) {not (initial-state), not (holding * o)} arm m (up to the wrist) clear of resting object o
ColHO(m,o) {not (holding m o)} -> same as ColAO     hand m clear of o, unless it has just let o go
ColOO(o,p) both resting, not stacked on each other  resting objects clear of each other
=========  ======================================  ===========================================

Grasp, Place and On act at the switch only (Equal carries them on): repeating them at every step
would add equalities that are redundant with Equal, which a Newton-type solver does not tolerate.
"""

from __future__ import annotations

import dataclasses
import itertools
from collections.abc import Mapping, Sequence

from rlgp_exec.planning.actions import PICKS
from rlgp_exec.planning.gnpp import drawer_pntc
from rlgp_exec.planning.gnpp.factor import INITIAL, MOVES, Factor, Var
from rlgp_exec.planning.gnpp.factor import partial_state as _ps
from rlgp_exec.planning.symbolic.model import Atom, GroundAction, GroundProblem, Operator, SymbolicState

__all__ = ["INITIAL", "MOVES", "Factor", "Var", "add_flags", "add_moves", "at_start", "factors_of", "moving", "parents"]

def add_flags(problem: GroundProblem) -> GroundProblem:
    """``problem`` with the flag atoms (at-init o) and (initial-state) (see the module docstring)."""
    objects = sorted(n for n, t in problem.objects if t == "movable")
    ops = []
    for op in problem.operators:
        dels = set(op.delete) | {INITIAL}
        if op.action.name in PICKS:
            dels.add(("at-init", op.action.args[1]))
        ops.append(Operator(op.action, op.pre, op.pre_neg, op.add, frozenset(dels), op.cond_effects))
    init = problem.init | {INITIAL} | {("at-init", o) for o in objects}
    return GroundProblem(
        problem.name, problem.domain_name, problem.objects, init, problem.goal, tuple(ops), problem.goal_neg
    )


def moving(arm: str) -> Atom:
    """The atom (moving m): the mobile arm m's base may move (between start-move and end-move)."""
    return ("moving", arm)


def at_start(arm: str) -> Atom:
    """The atom (base-at-start m): the mobile arm m's base has not moved yet (no start-move so far)."""
    return ("base-at-start", arm)


def add_moves(problem: GroundProblem, arms: Sequence[str], riders: Mapping[str, str] | None = None) -> GroundProblem:
    """``problem`` with start-move / end-move for each mobile arm in ``arms``, and pick / place / stack by
    it, or by an arm riding its base (``riders``: arm -> the mobile arm), only while it is not moving (see
    the module docstring)."""
    if not arms:
        return problem
    mover = {**{m: m for m in arms}, **(riders or {})}
    ops = []
    for op in problem.operators:
        arm = op.action.args[0] if op.action.args else None
        if arm is not None and arm in mover:
            op = Operator(op.action, op.pre, op.pre_neg | {moving(mover[arm])}, op.add, op.delete, op.cond_effects)
        ops.append(op)
    for m in arms:
        start, end = GroundAction(MOVES[0], (m,)), GroundAction(MOVES[1], (m,))
        ops.append(Operator(start, frozenset(), frozenset({moving(m)}), frozenset({moving(m)}),
                            frozenset({at_start(m)})))
        ops.append(Operator(end, frozenset({moving(m)}), frozenset(), frozenset(), frozenset({moving(m)})))
    return dataclasses.replace(problem, operators=tuple(ops), init=problem.init | {at_start(m) for m in arms})


def parents(state: SymbolicState) -> dict[str, str]:
    """parent(o) for every object: the support it is on, the cabinet whose drawer it is in, or the arm
    holding it."""
    out = {}
    for a in state:
        if a[0] in ("on", "in"):
            out[a[1]] = a[2]
        elif a[0] == "holding":
            out[a[2]] = a[1]
    return out


def _state_factors(
    t: int, s: SymbolicState, prev: SymbolicState | None, arms: list[str], movable: set[str],
    riders: Mapping[str, str],
) -> list[Factor]:
    out: list[Factor] = []
    par = parents(s)
    if INITIAL in s:
        out += [Factor(("RefQ", m), (Var("q", m, t),), ((t, _ps([INITIAL])),)) for m in arms]
    else:  # (at the start RefQ pins every base: a SameBase there would repeat an equality)
        out += [Factor(("SameBase", m, r), (Var("q", m, t), Var("q", r, t)), ((t, _ps((), [INITIAL])),))
                for r, m in sorted(riders.items())]
    resting = sorted(o for o in movable if o in par and par[o] not in arms)
    for o in resting:
        if ("at-init", o) in s:
            out.append(Factor(("Ref", o), (Var("x", o, t),), ((t, _ps([("at-init", o)])),)))
    # the objects on a support (world poses); those in a drawer (its frame) are ``drawer_pntc``'s
    resting = sorted(o for o in movable if o in par and par[o] not in arms and ("on", o, par[o]) in s)
    drawers = bool(drawer_pntc.cabinets(s))
    if INITIAL not in s:  # the start configuration is given (the tucked arms are not modelled by spheres)
        for m in arms:
            if drawers:
                out.append(drawer_pntc.colfix(t, s, prev, m))
            else:
                out.append(Factor(("ColFix", m), (Var("q", m, t),), ((t, _ps((), [INITIAL])),)))
        for ma, mb in itertools.combinations(arms, 2):
            out.append(Factor(("ColAA", ma, mb), (Var("q", ma, t), Var("q", mb, t)), ((t, _ps((), [INITIAL])),)))
        for m in arms:
            for o in resting:
                neg = [INITIAL] + [("holding", a, o) for a in arms]
                out.append(Factor(("ColAO", m, o), (Var("q", m, t), Var("x", o, t)), ((t, _ps((), neg)),)))
                if t > 0 and prev is not None and parents(prev).get(o) != m:  # not just let go by m
                    ps = ((t - 1, _ps((), [("holding", m, o)])), (t, _ps((), neg)))
                    out.append(Factor(("ColHO", m, o), (Var("q", m, t), Var("x", o, t)), ps))
    for a, b in itertools.combinations(resting, 2):
        if par[a] == b or par[b] == a:
            continue
        apart = [("holding", m, x) for m in arms for x in (a, b)] + [("on", a, b), ("on", b, a)]
        out.append(Factor(("ColOO", a, b), (Var("x", a, t), Var("x", b, t)), ((t, _ps((), apart)),)))
    if drawers:
        out += drawer_pntc.drawer_state_factors(t, s, prev, arms)
    return out


def _transition_factors(
    t: int, s: SymbolicState, s2: SymbolicState, arms: list[str], movable: set[str], mobile: Sequence[str]
) -> list[Factor]:
    out: list[Factor] = []
    for m in mobile:  # (a drawer's drive moves the base with the drawer: ``Drive``)
        if moving(m) not in s and moving(m) not in s2 and not drawer_pntc.drives(m, s, s2):
            ps = ((t, _ps((), [moving(m)])), (t + 1, _ps((), [moving(m)])))
            out.append(Factor(("EqualBase", m), (Var("q", m, t), Var("q", m, t + 1)), ps))
    p1, p2 = parents(s), parents(s2)
    for o in sorted(set(p1) & set(p2) & movable):
        a, b = p1[o], p2[o]
        x1, x2 = Var("x", o, t), Var("x", o, t + 1)
        if a == b and ("at-init", o) in s:
            continue  # Ref pins both
        if a == b:
            fact = ("holding", a, o) if a in arms else ("in", o, a) if ("in", o, a) in s else ("on", o, a)
            neg = [] if a in arms else [("at-init", o)]
            out.append(Factor(("Equal", "4"), (x1, x2), ((t, _ps([fact], neg)), (t + 1, _ps([fact])))))
        elif a not in arms and b in arms and ("on", o, a) in s:  # pick: the kinematic switch and the grasp
            ps = ((t, _ps([("on", o, a)])), (t + 1, _ps([("holding", b, o)])))
            out.append(Factor(("Kin", o, b), (Var("q", b, t + 1), x1, x2), ps))
            out.append(Factor(("Grasp", o), (x2,), ps))
        elif a in arms and ("in", o, b) in s2:  # drop: ``drawer_pntc``
            continue
        elif a in arms and b not in arms:  # place / stack: the kinematic switch and the placement
            ps = ((t, _ps([("holding", a, o)])), (t + 1, _ps([("on", o, b)])))
            out.append(Factor(("Kin", o, a), (Var("q", a, t + 1), x2, x1), ps))
            if b in movable:
                out.append(Factor(("On", o, b), (x2, Var("x", b, t + 1)), ps))
            else:
                out.append(Factor(("Place", o, b), (x2,), ps))
    if drawer_pntc.cabinets(s):
        holder = {o: p for o, p in p1.items() if p in arms}
        out += drawer_pntc.drawer_transition_factors(t, s, s2, arms, holder)
    return out


def factors_of(
    states: Sequence[SymbolicState], arms: Sequence[str], objects: Sequence[str], mobile: Sequence[str] = (),
    riders: Mapping[str, str] | None = None,
) -> list[Factor]:
    """Pi applied to a state sequence s_0 .. s_n: every factor of the graph-NLP, in time order
    (``mobile``: the arms with move operators, whose variable includes their base; ``riders``: arm ->
    the mobile arm whose base it shares; see ``add_moves``)."""
    arms_l, movable = list(arms), set(objects)
    out: list[Factor] = []
    for t, s in enumerate(states):
        out += _state_factors(t, s, states[t - 1] if t else None, arms_l, movable, riders or {})
        if t + 1 < len(states):
            out += _transition_factors(t, s, states[t + 1], arms_l, movable, mobile)
    return out
