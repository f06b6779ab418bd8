"""The graph-NLP (GNPP paper, Sec. IV): a bipartite graph of variables x_t^k and factors h_b, its
subgraphs, relaxations, connected components, time slices, semantic graphs for the isomorphism test,
and the trace back from a subgraph to the partial-state sequence that generates it (Sec. VII).

A subgraph is represented by its factors (Def. 4.2 with X_M = the variables its factors touch).
"""

from __future__ import annotations

import enum
from collections import Counter
from collections.abc import Iterable, Mapping, Sequence

import networkx as nx

from rlgp_exec.planning.gnpp.pntc import Factor, Var
from rlgp_exec.planning.symbolic.model import Atom
from rlgp_exec.planning.symbolic.reformulate import ForbiddenSequence, PartialState

__all__ = [
    "Relaxation",
    "components",
    "describe",
    "generalise",
    "relax",
    "semantic_graph",
    "structure",
    "time_slice",
    "times_of",
    "to_forbidden",
    "variables",
]


class Relaxation(enum.Flag):
    """Which variables/constraints a relaxation deletes (paper Sec. VIII-B; No Traj is implied: this
    graph has mode switches only)."""

    NONE = 0
    NO_ROBOT = enum.auto()  # robot variables and every factor on them
    NO_COL = enum.auto()  # collision factors between two variables (arm-arm, arm-object, object-object)
    NO_TIME = enum.auto()  # time-consistency factors (Equal)


#: the paper's order (Appendix C), loose to tight; the last entry is the full (mode-switch) graph
PAPER_ORDER: tuple[Relaxation, ...] = (
    Relaxation.NO_ROBOT | Relaxation.NO_COL,
    Relaxation.NO_COL,
    Relaxation.NO_ROBOT | Relaxation.NO_TIME,
    Relaxation.NO_TIME,
    Relaxation.NONE,
)


def relax(factors: Iterable[Factor], r: Relaxation) -> list[Factor]:
    out = []
    for f in factors:
        if Relaxation.NO_ROBOT in r and f.robot:
            continue
        if Relaxation.NO_COL in r and f.coupling:
            continue
        if Relaxation.NO_TIME in r and f.time_consistency:
            continue
        out.append(f)
    return out


def variables(factors: Iterable[Factor]) -> list[Var]:
    return sorted({v for f in factors for v in f.vars})


def components(factors: Sequence[Factor]) -> list[list[Factor]]:
    """Connected components (Property 4.5), each in the input order, largest time span last."""
    parent: dict[Var, Var] = {}

    def find(v: Var) -> Var:
        while parent.setdefault(v, v) != v:
            parent[v] = parent[parent[v]]
            v = parent[v]
        return v

    for f in factors:
        root = find(f.vars[0])
        for v in f.vars[1:]:
            parent[find(v)] = root
    groups: dict[Var, list[Factor]] = {}
    for f in factors:
        groups.setdefault(find(f.vars[0]), []).append(f)
    return sorted(groups.values(), key=lambda g: (times_of(g)[1] - times_of(g)[0], len(g)))


def times_of(factors: Iterable[Factor]) -> tuple[int, int]:
    ts = [t for f in factors for t in f.times]
    return min(ts), max(ts)


def time_slice(factors: Iterable[Factor], first: int, last: int) -> list[Factor]:
    """G[first .. last]: the factors whose variables all lie in that time window."""
    return [f for f in factors if f.times[0] >= first and f.times[1] <= last]


def semantic_graph(factors: Iterable[Factor], context: Mapping[tuple[str, ...], str] | None = None) -> nx.Graph:
    """The labelled bipartite graph: variable nodes labelled (kind, owner), factor nodes labelled by
    their function key (plus ``context[key]`` where the call's numbers give the key its meaning, e.g. an
    object's initial pose), edges by the variable's slot in the factor (time indices left out)."""
    g = nx.Graph()
    ctx = context or {}
    for i, f in enumerate(factors):
        g.add_node(("f", i), label=("f", *f.key, *((ctx[f.key],) if f.key in ctx else ())))
        for slot, v in enumerate(f.vars):
            g.add_node(v, label=v.label)
            g.add_edge(("f", i), v, slot=slot)
    return g


def structure(factors: Iterable[Factor]) -> tuple:
    """The subgraph's NLP up to the names of its variables: the variables' labels in order and each
    factor's key with its variables' positions, time indices left out and the variables an ``Equal``
    factor makes equal merged into one (an exact equality of the whole pose: an object held, or left
    standing, a few steps longer gives the same problem). Subgraphs of one scene with the same
    structure are the same NLP up to renaming (a factor's function and a variable's bounds depend on
    its key and label only: Pi is time-invariant), so they are both feasible or both infeasible."""
    return canonical(factors)[0]


def canonical(factors: Iterable[Factor]) -> tuple[tuple, dict[Var, int]]:
    """(``structure(factors)``, each variable's position in it): a feasible point of one subgraph, its
    values by position, is a feasible point of any other subgraph with the same structure (``Equal``-merged
    variables share their position)."""
    fs = list(factors)
    rep: dict[Var, Var] = {}

    def find(v: Var) -> Var:
        while v in rep:
            v = rep[v]
        return v

    for f in fs:
        if f.kind == "Equal":
            a, b = sorted(find(v) for v in f.vars)
            if a != b:
                rep[b] = a
    rest = [f for f in fs if f.kind != "Equal"]
    order = sorted({find(v) for f in rest for v in f.vars})
    pos = {v: i for i, v in enumerate(order)}
    key = (
        tuple(v.label for v in order),
        tuple(sorted((f.key, tuple(pos[find(v)] for v in f.vars)) for f in rest)),
    )
    return key, {v: pos[find(v)] for f in fs for v in f.vars if find(v) in pos}


def to_forbidden(factors: Iterable[Factor]) -> ForbiddenSequence:
    """The partial-state sequence <p_0 .. p_L> whose facts generate exactly these factors (Sec. VII)."""
    by_t: dict[int, tuple[set[Atom], set[Atom]]] = {}
    for f in factors:
        for t, p in f.partial:
            pos, neg = by_t.setdefault(t, (set(), set()))
            pos |= p.pos
            neg |= p.neg
    lo, hi = min(by_t), max(by_t)
    seq = []
    for t in range(lo, hi + 1):
        pos, neg = by_t.get(t, (set(), set()))
        seq.append(PartialState(frozenset(pos), frozenset(neg)))
    return ForbiddenSequence(tuple(seq))


#: the one-variable factors on an object's pose that hold all along the pose's ``Equal`` chain once they hold
#: at one end (the chain makes the poses equal): a grasp while held, a placement while resting there
_CARRIED = ("Grasp", "Place")
#: ... and the stacking factor, on two poses: it stays where it is, its partial states reduced as theirs
_STACKED = "On"


def generalise(factors: Sequence[Factor]) -> tuple[Factor, ...]:
    """A conflict with each ``Grasp`` / ``Place`` factor moved along its object's ``Equal`` chain to the
    step where another factor of the conflict uses the pose, the chain dropped, and its partial states
    reduced to the fact that carries it to that step: (holding m o) for a grasp, (on o s) and not
    (at-init o) for a placement or a stacking (``On``, left at its step). The same NLP up to
    ``presolve`` (the chain made the poses one); its ``to_forbidden`` names neither where nor how many
    steps before the object was picked up or put down. Sound for the plans the planner checks (pick,
    place, stack): holding at t means picked at some p <= t (a ``Grasp`` at p, ``Equal`` from p to t);
    resting on s, not at its start, means put on s at some p <= t (a ``Place`` or ``On`` at p, ``Equal``
    since, for s too: an object with another on it is not picked). On Hanoi the same "arm m cannot put
    o on s" was learnt once per pick site and holding time (6 of 12 conflicts). Other factors stay."""
    fs = list(factors)
    users = Counter(v for f in fs if f.kind != "Equal" for v in f.vars)
    chain: dict[Var, list[tuple[Var, Factor]]] = {}
    for f in fs:
        if f.kind == "Equal":
            a, b = f.vars
            chain.setdefault(a, []).append((b, f))
            chain.setdefault(b, []).append((a, f))
    dropped: set[Factor] = set()
    out: list[Factor] = []
    for f in fs:
        if f.kind == _STACKED:
            out.append(Factor(f.key, f.vars, ((f.times[1], _carrier(f)),)))
            continue
        if f.kind not in _CARRIED:
            out.append(f)
            continue
        start = cur = f.vars[0]
        prev, walked = None, []
        while users[cur] == (1 if cur == start else 0):  # nothing else of the conflict uses this pose
            step = [(v, e) for v, e in chain.get(cur, []) if v != prev]
            if len(step) != 1:
                break
            walked.append(step[0][1])
            prev, cur = cur, step[0][0]
        if cur != start and users[cur] == 0:  # a chain that leads nowhere (not minimal): left as found
            out.append(f)
            continue
        dropped.update(walked)
        out.append(Factor(f.key, (cur,), ((cur.t, _carrier(f)),)))
    return tuple(g for g in out if g not in dropped)


def _carrier(f: Factor) -> PartialState:
    """The partial state that makes ``f`` (``_CARRIED`` or ``_STACKED``) hold at a step (``generalise``)."""
    o = f.key[1]
    if f.kind == "Grasp":
        arm = next(a[1] for _, p in f.partial for a in p.pos if a[0] == "holding" and a[2] == o)
        return PartialState(frozenset({("holding", arm, o)}))
    return PartialState(frozenset({("on", o, f.key[2])}), frozenset({("at-init", o)}))


def describe(factors: Iterable[Factor]) -> str:
    return "; ".join(str(f) for f in factors)
