"""The PNTC model's variables and factors (GNPP paper, Sec. III; ``pntc`` maps logic states to them)."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

from rlgp_exec.planning.actions import MOVES  # the paper's move operators (a mobile arm's base)
from rlgp_exec.planning.symbolic.model import Atom
from rlgp_exec.planning.symbolic.reformulate import PartialState

__all__ = ["COLLISION", "COUPLING_COLLISION", "INITIAL", "MOVES", "TIME", "Factor", "Var", "partial_state"]

INITIAL: Atom = ("initial-state",)
COLLISION = ("ColFix", "ColAA", "ColAO", "ColHO", "ColOO")
#: the collision factors the "No Col" relaxation removes: those between two variables, which make a time
#: step's graph dense (paper Sec. VIII-B). ColFix (one arm against the fixed world, with the PR2's
#: pan/wrist limits) has one variable: it connects nothing, and it is what makes most reach conflicts
COUPLING_COLLISION = ("ColAA", "ColAO", "ColHO", "ColOO")
TIME = ("Equal", "EqualBase")


@dataclass(frozen=True, order=True)
class Var:
    """x_t^k: ``kind`` "q" (an arm's joints, 7) or "x" (an object's pose, 4), ``owner``, time ``t``."""

    kind: str
    owner: str
    t: int

    @property
    def label(self) -> tuple[str, str]:
        """The semantic label (time left out), for the subgraph-isomorphism test."""
        return (self.kind, self.owner)

    def __str__(self) -> str:
        return f"{self.kind}[{self.owner}]@{self.t}"


@dataclass(frozen=True)
class Factor:
    """A constraint h_b: function key (kind, args...), its variables in slot order, and the partial
    states (by time index) that generated it under Pi."""

    key: tuple[str, ...]
    vars: tuple[Var, ...]
    partial: tuple[tuple[int, PartialState], ...] = field(compare=False)

    @property
    def kind(self) -> str:
        return self.key[0]

    @property
    def collision(self) -> bool:
        return self.kind in COLLISION

    @property
    def coupling(self) -> bool:
        """A collision factor between two variables (see ``COUPLING_COLLISION``)."""
        return self.kind in COUPLING_COLLISION

    @property
    def time_consistency(self) -> bool:
        return self.kind in TIME

    @property
    def robot(self) -> bool:
        return any(v.kind == "q" for v in self.vars)

    @property
    def times(self) -> tuple[int, int]:
        ts = [v.t for v in self.vars]
        return min(ts), max(ts)

    def __str__(self) -> str:
        return f"{'/'.join(self.key)}({', '.join(map(str, self.vars))})"


def partial_state(pos: Sequence[Atom] = (), neg: Sequence[Atom] = ()) -> PartialState:
    """The partial state with ``pos`` true and ``neg`` false."""
    return PartialState(frozenset(pos), frozenset(neg))
