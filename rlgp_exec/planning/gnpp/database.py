"""Databases of solved subgraphs (GNPP paper, Sec. VI-E): a subgraph that is (semantically) a subgraph
of a known feasible graph is feasible; one that contains a known infeasible graph is infeasible —
either way no NLP is solved.

The test is networkx's VF2 matcher on the labelled bipartite graphs of ``graph.semantic_graph``
(variable nodes by (kind, owner), factor nodes by function key, edges by argument slot; time indices
are left out), as a monomorphism: the smaller graph's factors must all appear, with the same variables
shared the same way, in the larger one. A count of labels filters candidates before VF2 runs.

A database outlives one planning call (the executive's replans keep it in ``PlannerMemory``): the
factors whose meaning depends on the call's numbers — an object's initial pose (``Ref``), an arm's
initial configuration (``RefQ``) — are labelled with a digest of those numbers (:meth:`SubgraphDB.bind`),
so a subgraph learnt with a block at one place never answers for the block somewhere else, while
one without such factors (a grasp and a placement out of one arm's reach) answers in every call.
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import networkx as nx
from networkx.algorithms import isomorphism as iso

from rlgp_exec.planning.gnpp.graph import semantic_graph
from rlgp_exec.planning.gnpp.pntc import Factor

__all__ = ["SubgraphDB"]

log = logging.getLogger(__name__)

_node_match = iso.categorical_node_match("label", None)
_edge_match = iso.categorical_edge_match("slot", None)


@dataclass
class _Entry:
    graph: nx.Graph
    labels: Counter


def _entry(factors: Sequence[Factor], context: Mapping[tuple[str, ...], str]) -> _Entry:
    g = semantic_graph(factors, context)
    return _Entry(g, Counter(d["label"] for _, d in g.nodes(data=True)))


def _contains(big: _Entry, small: _Entry) -> bool:
    if any(big.labels[k] < n for k, n in small.labels.items()):
        return False
    return iso.GraphMatcher(big.graph, small.graph, _node_match, _edge_match).subgraph_is_monomorphic()


class SubgraphDB:
    """Feasible and infeasible subgraphs seen so far; ``hits`` counts solves avoided."""

    def __init__(self) -> None:
        self.feasible: list[_Entry] = []
        self.infeasible: list[_Entry] = []
        self.hits = 0
        self.context: dict[tuple[str, ...], str] = {}

    def bind(self, context: Mapping[tuple[str, ...], str]) -> None:
        """The current call's digests per factor key (see the module docstring); used from now on."""
        self.context = dict(context)

    def add(self, factors: Sequence[Factor], feasible: bool) -> None:
        (self.feasible if feasible else self.infeasible).append(_entry(factors, self.context))

    def correct(self, factors: Sequence[Factor]) -> int:
        """``factors`` turned out feasible (another start of the local solver): record it, and drop the
        infeasible entries it contradicts (those that are subgraphs of it). Returns how many."""
        e = _entry(factors, self.context)
        keep = [k for k in self.infeasible if not _contains(e, k)]
        dropped = len(self.infeasible) - len(keep)
        self.infeasible = keep
        self.feasible.append(e)
        return dropped

    def lookup(self, factors: Sequence[Factor]) -> bool | None:
        """True if known feasible, False if known infeasible, None if unknown."""
        q = _entry(factors, self.context)
        if any(_contains(e, q) for e in reversed(self.feasible)):
            self.hits += 1
            return True
        if any(_contains(q, e) for e in reversed(self.infeasible)):
            self.hits += 1
            return False
        return None
