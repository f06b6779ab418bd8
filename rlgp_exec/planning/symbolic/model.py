"""The ground STRIPS successor model: atoms, ground actions, operators, states, successors, goal test.

Semantics are Fast Downward's: an operator applies when its positive preconditions hold and its
negative ones do not; conditional effects are evaluated on the state before the action; all
deletes are applied before all adds (an atom both added and deleted ends up true).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

from rlgp_exec.planning.symbolic.errors import SymbolicError

__all__ = [
    "Atom",
    "CondEffect",
    "GroundAction",
    "GroundProblem",
    "Operator",
    "SymbolicState",
    "atom_str",
    "parse_atom",
]

#: A ground atom: (predicate, arg, ...), e.g. ("on", "block_a", "tray").
Atom = tuple[str, ...]
#: A symbolic state: the set of true atoms (closed world).
SymbolicState = frozenset[Atom]


def atom_str(atom: Atom) -> str:
    return f"({' '.join(atom)})"


def parse_atom(text: str) -> Atom:
    """``"(on a b)"`` -> ("on", "a", "b")."""
    t = text.strip()
    if not (t.startswith("(") and t.endswith(")")) or not t[1:-1].split():
        raise SymbolicError(f"{text!r} is not an atom like '(on block tray)'")
    return tuple(t[1:-1].split())


@dataclass(frozen=True, order=True)
class GroundAction:
    """An action of a plan, e.g. ``GroundAction("pick", ("right_arm", "b1", "table"))``."""

    name: str
    args: tuple[str, ...]

    def __str__(self) -> str:
        return f"({' '.join((self.name, *self.args))})"

    @staticmethod
    def parse(text: str) -> GroundAction:
        """``"(pick arm b1 table)"`` -> GroundAction."""
        atom = parse_atom(text)
        return GroundAction(atom[0], atom[1:])


@dataclass(frozen=True)
class CondEffect:
    """``(when (and cond (not cond_neg)) (and add (not delete)))``."""

    cond: frozenset[Atom]
    cond_neg: frozenset[Atom] = frozenset()
    add: frozenset[Atom] = frozenset()
    delete: frozenset[Atom] = frozenset()

    def fires(self, state: SymbolicState) -> bool:
        return self.cond <= state and self.cond_neg.isdisjoint(state)


@dataclass(frozen=True)
class Operator:
    action: GroundAction
    pre: frozenset[Atom]
    pre_neg: frozenset[Atom]
    add: frozenset[Atom]
    delete: frozenset[Atom]
    cond_effects: tuple[CondEffect, ...] = ()

    def applicable(self, state: SymbolicState) -> bool:
        return self.pre <= state and self.pre_neg.isdisjoint(state)

    def apply(self, state: SymbolicState) -> SymbolicState:
        """The successor (applicability is not checked)."""
        if not self.cond_effects:
            return (state - self.delete) | self.add
        add, delete = set(self.add), set(self.delete)
        for ce in self.cond_effects:
            if ce.fires(state):
                add |= ce.add
                delete |= ce.delete
        return (state - delete) | add


@dataclass(frozen=True)
class GroundProblem:
    """A grounded planning task; ``objects`` keeps the typed names for writing PDDL."""

    name: str
    domain_name: str
    objects: tuple[tuple[str, str], ...]  # (name, most specific type)
    init: SymbolicState
    goal: frozenset[Atom]
    operators: tuple[Operator, ...]
    goal_neg: frozenset[Atom] = frozenset()
    #: atoms that must stay true (never re-added once lost): a state without one is a dead end
    required: frozenset[Atom] = frozenset()
    _by_action: dict[GroundAction, Operator] = field(init=False, repr=False, compare=False)
    #: operator indices by one positive precondition each (the one fewest operators share): only the
    #: operators triggered by an atom of the state can apply; ``_always``: those without a precondition
    _triggered: dict[Atom, tuple[int, ...]] = field(init=False, repr=False, compare=False)
    _always: tuple[int, ...] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        object.__setattr__(self, "_by_action", {op.action: op for op in self.operators})
        share: dict[Atom, int] = {}
        for op in self.operators:
            for a in op.pre:
                share[a] = share.get(a, 0) + 1
        triggered: dict[Atom, list[int]] = {}
        always = []
        for i, op in enumerate(self.operators):
            if op.pre:
                triggered.setdefault(min(op.pre, key=lambda a: (share[a], a)), []).append(i)
            else:
                always.append(i)
        object.__setattr__(self, "_triggered", {a: tuple(ix) for a, ix in triggered.items()})
        object.__setattr__(self, "_always", tuple(always))

    def is_goal(self, state: SymbolicState) -> bool:
        return self.goal <= state and self.goal_neg.isdisjoint(state)

    def successors(self, state: SymbolicState) -> list[tuple[GroundAction, SymbolicState]]:
        """Applicable actions and their successor states (dead ends, see ``required``, left out)."""
        cand = list(self._always)
        for atom in state:
            cand.extend(self._triggered.get(atom, ()))
        cand.sort()  # the operators' order, as a scan of all of them gives
        ops = self.operators
        out = [(ops[i].action, ops[i].apply(state)) for i in cand if ops[i].applicable(state)]
        if self.required:
            out = [(a, s) for a, s in out if self.required <= s]
        return out

    def operator(self, action: GroundAction) -> Operator:
        try:
            return self._by_action[action]
        except KeyError:
            names = sorted({op.action.name for op in self.operators})
            raise SymbolicError(
                f"{self.name}: no ground action {action}; valid action names: {names} "
                f"(with typed arguments of this problem)"
            ) from None

    def simulate(self, plan: Sequence[GroundAction], state: Iterable[Atom] | None = None) -> list[SymbolicState]:
        """The states along ``plan`` from ``state`` (default init), start included; raises on an inapplicable step."""
        s: SymbolicState = self.init if state is None else frozenset(state)
        states = [s]
        for i, a in enumerate(plan):
            op = self.operator(a)
            if not op.applicable(s):
                missing = sorted(atom_str(x) for x in op.pre - s)
                present = sorted(atom_str(x) for x in op.pre_neg & s)
                raise SymbolicError(
                    f"{self.name}: step {i} {a} is not applicable: missing {missing}, must not hold {present}"
                )
            s = op.apply(s)
            states.append(s)
        return states

    def reaches_goal(self, plan: Sequence[GroundAction]) -> bool:
        """True iff ``plan`` applies step by step from init and ends in a goal state."""
        try:
            return self.is_goal(self.simulate(plan)[-1])
        except SymbolicError:
            return False
