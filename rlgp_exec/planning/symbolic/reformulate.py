"""GNPP logic reformulation: forbid plans that contain a learnt infeasible pattern.

A minimal infeasible subgraph traces back (GNPP paper, Sec. VII) to a sequence of partial states
``<p_0 ... p_L>`` that must not hold on *consecutive* states of a plan: :class:`ForbiddenSequence`.
The compilation is the paper's (Appendix B): flags ``b_0 .. b_{L-1}`` mark that the path so far
ends with a match of ``p_0 .. p_l``; every action gets the conditional effects

* ``(p_0 holds after a) |> b_0 := 1``
* ``b_{l-1} and (p_l holds after a) |> b_l := 1`` for l = 1..L, and ``b_{l-1} := 0`` otherwise,

where "p holds after a" is evaluated on the state before ``a`` with ``a``'s effects taken into
account (false if ``a`` deletes a fact of ``p``). ``b_L = 1`` is a dead end: we keep a positive
flag ``ok`` instead, deleted where the paper sets ``b_L``, required by the goal (so STRIPS goals
stay positive). Proposition 7.1 of the paper: a plan solves the new task iff it solves the old
one and its state sequence contains no forbidden subsequence.

:class:`ForbiddenActions` is the unordered variant: a set of action patterns (ground actions or
actions with wildcard arguments) that must not all occur in one plan, compiled with "seen" flags.

The reformulated problem is a :class:`GroundProblem` with the same ground actions: Fast Downward
reads it through ``ground_pddl`` / ``downward.solve_ground``; our own ``best_first`` searches it
directly, where a lost ``ok`` flag is a dead end (``GroundProblem.required``) — one compilation,
both planners.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.model import (
    Atom,
    CondEffect,
    GroundAction,
    GroundProblem,
    Operator,
    SymbolicState,
    atom_str,
    parse_atom,
)

__all__ = [
    "ActionPattern",
    "ForbiddenActions",
    "ForbiddenSequence",
    "PartialState",
    "Reformulation",
    "reformulate",
    "violates",
]

log = logging.getLogger(__name__)


def _atoms(items: Iterable[Atom | str]) -> frozenset[Atom]:
    return frozenset(parse_atom(x) if isinstance(x, str) else tuple(x) for x in items)


@dataclass(frozen=True)
class PartialState:
    """Facts that hold (``pos``) and facts that do not hold (``neg``)."""

    pos: frozenset[Atom]
    neg: frozenset[Atom] = frozenset()

    @staticmethod
    def of(pos: Iterable[Atom | str] = (), neg: Iterable[Atom | str] = ()) -> PartialState:
        return PartialState(_atoms(pos), _atoms(neg))

    def holds(self, state: SymbolicState) -> bool:
        return self.pos <= state and self.neg.isdisjoint(state)

    def __str__(self) -> str:
        return (
            "{"
            + ", ".join([atom_str(a) for a in sorted(self.pos)] + [f"(not {atom_str(a)})" for a in sorted(self.neg)])
            + "}"
        )


@dataclass(frozen=True)
class ForbiddenSequence:
    """``<p_0 ... p_L>``: no plan may pass through states s_i ... s_{i+L} with p_l in s_{i+l}."""

    states: tuple[PartialState, ...]

    def __post_init__(self) -> None:
        if not self.states:
            raise SymbolicError("ForbiddenSequence: needs at least one partial state")

    def occurs_in(self, states: Sequence[SymbolicState]) -> bool:
        n = len(self.states)
        return any(all(p.holds(states[i + k]) for k, p in enumerate(self.states)) for i in range(len(states) - n + 1))


@dataclass(frozen=True)
class ActionPattern:
    """An action with some arguments fixed (``None`` = any), e.g. ``pick(right_arm, b2, *)``."""

    name: str
    args: tuple[str | None, ...]

    @staticmethod
    def of(action: GroundAction | str) -> ActionPattern:
        """From a ground action or a text like ``"(pick right_arm b2 *)"``."""
        a = GroundAction.parse(action) if isinstance(action, str) else action
        return ActionPattern(a.name, tuple(None if x in ("*", "?") else x for x in a.args))

    def matches(self, action: GroundAction) -> bool:
        return (
            action.name == self.name
            and len(action.args) == len(self.args)
            and all(p is None or p == x for p, x in zip(self.args, action.args, strict=True))
        )


@dataclass(frozen=True)
class ForbiddenActions:
    """Action patterns that must not all appear in the same plan (in any order)."""

    patterns: frozenset[ActionPattern]

    def __post_init__(self) -> None:
        if not self.patterns:
            raise SymbolicError("ForbiddenActions: needs at least one action pattern")

    def occurs_in(self, plan: Sequence[GroundAction]) -> bool:
        return all(any(p.matches(a) for a in plan) for p in self.patterns)


Forbidden = ForbiddenSequence | ForbiddenActions


def violates(plan: Sequence[GroundAction], states: Sequence[SymbolicState], forbidden: Iterable[Forbidden]) -> bool:
    """Direct check (no compilation): does the plan, with its states init..end, contain a forbidden pattern?"""
    return any(f.occurs_in(states) if isinstance(f, ForbiddenSequence) else f.occurs_in(plan) for f in forbidden)


def _after(op: Operator, p: PartialState) -> tuple[frozenset[Atom], frozenset[Atom]] | None:
    """Condition on the state before ``op`` for ``p`` to hold after it, or None if it never does."""
    if (p.pos & op.delete) - op.add or p.neg & op.add:
        return None
    return p.pos - op.add, p.neg - op.delete


@dataclass(frozen=True)
class Reformulation:
    problem: GroundProblem  # the compiled task (same ground actions, extra flag atoms)
    original: GroundProblem
    forbidden: tuple[Forbidden, ...]
    flags: frozenset[Atom]  # the atoms the compilation added

    def project(self, state: SymbolicState) -> SymbolicState:
        """A compiled state without the flag atoms."""
        return state - self.flags


def _compile_sequence(
    k: int,
    seq: ForbiddenSequence,
    ops: list[Operator],
    extra: dict[int, list[CondEffect]],
    dels: dict[int, set[Atom]],
    init: set[Atom],
) -> Atom:
    L = len(seq.states) - 1
    ok: Atom = (f"fseq{k}-ok",)
    b = [(f"fseq{k}-b{lvl}",) for lvl in range(L)]
    if L == 0:
        if not seq.states[0].holds(frozenset(init)):
            init.add(ok)
    else:
        init.add(ok)
        if seq.states[0].holds(frozenset(init)):
            init.add(b[0])
    for i, op in enumerate(ops):
        for lvl, p in enumerate(seq.states):
            c = _after(op, p)
            if c is None:
                continue
            cond = set(c[0]) | ({b[lvl - 1]} if lvl > 0 else set())
            effect = (
                CondEffect(frozenset(cond), c[1], delete=frozenset({ok}))
                if lvl == L
                else CondEffect(frozenset(cond), c[1], add=frozenset({b[lvl]}))
            )
            extra.setdefault(i, []).append(effect)
        dels.setdefault(i, set()).update(b)  # b_l := 0 unless re-set above (adds win over deletes)
    return ok


def _compile_actions(
    k: int,
    fa: ForbiddenActions,
    ops: list[Operator],
    extra: dict[int, list[CondEffect]],
    adds: dict[int, set[Atom]],
    init: set[Atom],
) -> Atom:
    patterns = sorted(fa.patterns, key=str)
    ok: Atom = (f"fset{k}-ok",)
    seen = [(f"fset{k}-seen{j}",) for j in range(len(patterns))]
    init.add(ok)
    for i, op in enumerate(ops):
        hit = {j for j, p in enumerate(patterns) if p.matches(op.action)}
        if not hit:
            continue
        adds.setdefault(i, set()).update(seen[j] for j in hit)
        rest = frozenset(seen[j] for j in range(len(patterns)) if j not in hit)
        extra.setdefault(i, []).append(CondEffect(rest, delete=frozenset({ok})))
    return ok


def reformulate(problem: GroundProblem, forbidden: Iterable[Forbidden]) -> Reformulation:
    """The task of ``problem`` without the plans that contain any of ``forbidden``.

    Call it on the original (unreformulated) problem with the whole, growing set of forbidden
    patterns: it compiles them all at once.
    """
    forbidden = tuple(forbidden)
    if any(op.cond_effects for op in problem.operators):
        raise SymbolicError(
            f"{problem.name}: already has conditional effects; reformulate the original "
            "problem with all forbidden patterns at once"
        )
    known = set(problem.init) | {a for op in problem.operators for a in op.add | op.pre}
    ops = list(problem.operators)
    init = set(problem.init)
    extra: dict[int, list[CondEffect]] = {}
    dels: dict[int, set[Atom]] = {}
    adds: dict[int, set[Atom]] = {}
    oks: list[Atom] = []
    for k, f in enumerate(forbidden):
        if isinstance(f, ForbiddenSequence):
            unknown = sorted(atom_str(a) for p in f.states for a in p.pos - known)
            if unknown:
                log.warning("forbidden sequence %d names atoms that never hold in %s: %s", k, problem.name, unknown)
            oks.append(_compile_sequence(k, f, ops, extra, dels, init))
        elif isinstance(f, ForbiddenActions):
            names = {op.action.name for op in ops}
            bad = sorted(p.name for p in f.patterns if p.name not in names)
            if bad:
                raise SymbolicError(
                    f"forbidden actions {bad} are not actions of {problem.name}; valid: {sorted(names)}"
                )
            oks.append(_compile_actions(k, f, ops, extra, adds, init))
        else:
            raise SymbolicError(f"cannot forbid {f!r}; valid: ForbiddenSequence, ForbiddenActions")
    new_ops = tuple(
        Operator(
            op.action,
            op.pre,
            op.pre_neg,
            op.add | adds.get(i, set()),
            op.delete | dels.get(i, set()),
            tuple(extra.get(i, ())),
        )
        for i, op in enumerate(ops)
    )
    flags = {a for op in new_ops for ce in op.cond_effects for a in ce.add | ce.delete}
    flags |= {a for i in dels for a in dels[i]} | {a for i in adds for a in adds[i]} | set(oks)
    compiled = GroundProblem(
        problem.name,
        problem.domain_name,
        problem.objects,
        frozenset(init),
        problem.goal | frozenset(oks),
        new_ops,
        problem.goal_neg,
        problem.required | frozenset(oks),
    )
    log.debug("reformulated %s with %d forbidden patterns (%d flag atoms)", problem.name, len(forbidden), len(flags))
    return Reformulation(compiled, problem, forbidden, frozenset(flags))
