"""Finding a small infeasible subgraph (GNPP paper, Sec. VI and Alg. 1 of the appendix).

For each relaxation in order (loose to tight) the relaxed graph is split into connected components;
each component is solved; the first infeasible one is cut down by the double binary search on the
time index, then (``convergence``) to the factors violated at the optimizer's convergence point if
those alone are infeasible, and finally by a deletion filter (each factor dropped in turn, kept out
if the rest stays infeasible) so that the conflict is minimal (Def. 4.4): infeasible, and feasible
without any one of its factors. Every solve goes through ``Checker`` (counts, optional database).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from rlgp_exec.planning.gnpp.database import SubgraphDB
from rlgp_exec.planning.gnpp.graph import PAPER_ORDER, Relaxation, components, relax, time_slice, times_of
from rlgp_exec.planning.gnpp.pntc import Factor, Var
from rlgp_exec.planning.gnpp.solver import GraphSolver, SolveResult
from rlgp_exec.robot.model import FloatArray

__all__ = ["Checker", "Conflict", "DeadlineError", "ExtractOptions", "find_conflict"]

log = logging.getLogger(__name__)
FILTER_MAX = 12  # the deletion filter (one solve per factor) runs on conflicts up to this size
FILTER_MAX_NO_ROBOT = 40  # ... or this size when no factor has an arm variable (object poses only)


@dataclass(frozen=True)
class ExtractOptions:
    time_search: bool = True  # t
    relaxations: bool = True  # r
    convergence: bool = True  # n (with the deletion filter)
    database: bool = False  # g


@dataclass(frozen=True)
class Conflict:
    factors: tuple[Factor, ...]
    relaxation: Relaxation

    def __str__(self) -> str:
        return " ; ".join(str(f) for f in self.factors)


class DeadlineError(Exception):
    """The planner's time budget ran out in the middle of a conflict search (internal: caught by it)."""


class Checker:
    """Feasibility of subgraphs: the database first (if any), else an NLP solve (counted); raises
    ``DeadlineError`` once ``time.perf_counter()`` passes ``deadline``."""

    def __init__(
        self,
        solver: GraphSolver,
        guess: Mapping[Var, FloatArray],
        db: SubgraphDB | None = None,
        deadline: float = float("inf"),
    ) -> None:
        self.solver, self.guess, self.db, self.deadline = solver, dict(guess), db, deadline
        self.last: SolveResult | None = None

    def feasible(self, factors: Sequence[Factor]) -> bool:
        if not factors:
            return True
        if time.perf_counter() > self.deadline:
            raise DeadlineError
        self.last = None
        if self.db is not None:
            known = self.db.lookup(factors)
            if known is not None:
                return known
        res = self.solver.solve(factors, self.guess)
        self.last = res
        if self.db is not None:
            self.db.add(factors, res.feasible)
        return res.feasible


def _time_search(check: Checker, g: list[Factor]) -> list[Factor]:
    """The minimal time window [f, l] of an infeasible component (double binary search)."""
    t0, t1 = times_of(g)
    lo, hi = t0, t1  # smallest l with G[t0 .. l] infeasible; G[t0 .. t1] is
    while lo < hi:
        mid = (lo + hi) // 2
        if check.feasible(time_slice(g, t0, mid)):
            lo = mid + 1
        else:
            hi = mid
    last = hi
    lo, hi = t0, last  # largest f with G[f .. last] infeasible; G[t0 .. last] is
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if check.feasible(time_slice(g, mid, last)):
            hi = mid - 1
        else:
            lo = mid
    return time_slice(g, lo, last)


def _convergence(check: Checker, g: list[Factor]) -> list[Factor]:
    """The factors violated at the convergence point, if they alone are infeasible (Sec. VI-C), else
    those with the factors over their variables only, if that is infeasible; else ``g``."""
    if check.feasible(g) or check.last is None:
        return g
    violated = [f for f, v in zip(g, check.last.violations, strict=True) if v > 1e-4]
    if not violated:
        return g
    # with the factors that only constrain the violated ones' variables (e.g. the Ref pinning an
    # obstacle a violated collision names): those alone are rarely infeasible without them
    span = {v for f in violated for v in f.vars}
    closed = [f for f in g if f in violated or set(f.vars) <= span]
    for cand in (violated, closed):
        if len(cand) < len(g) and not check.feasible(cand):
            return cand
    return g


def _deletion_filter(check: Checker, g: list[Factor]) -> list[Factor]:
    out = list(g)
    for f in list(g):
        trial = [h for h in out if h is not f]
        if trial and not check.feasible(trial):
            out = trial
    # a minimal infeasible subgraph is connected (Property 4.5): keep the infeasible component
    comps = components(out)
    if len(comps) > 1:
        for c in comps:
            if not check.feasible(c):
                return c
    return out


def find_conflict(
    check: Checker, graph: Sequence[Factor], opts: ExtractOptions
) -> tuple[Conflict | None, dict[Var, FloatArray]]:
    """(a small infeasible subgraph, or None and the convergence point of the full graph)."""
    order = PAPER_ORDER if opts.relaxations else (Relaxation.NONE,)
    values: dict[Var, FloatArray] = {}
    for rel in order:
        for comp in components(relax(graph, rel)):
            if check.feasible(comp):
                if check.last is not None:  # a looser relaxation's solution warm-starts the tighter ones
                    check.guess.update(check.last.values)
                if rel is Relaxation.NONE and check.last is not None:
                    values.update(check.last.values)
                elif rel is Relaxation.NONE:  # a database hit: the values are solved for the plan
                    res = check.solver.solve(comp, check.guess)
                    if not res.feasible:  # the solver disagrees with the database: trust the solve
                        return Conflict(tuple(comp), rel), {}
                    values.update(res.values)
                continue
            sub = _time_search(check, comp) if opts.time_search else comp
            if opts.convergence:
                sub = _convergence(check, sub)
                # larger ones stay as found (small, not proven minimal); without arms the NLPs are tiny
                if len(sub) <= (FILTER_MAX_NO_ROBOT if not any(f.robot for f in sub) else FILTER_MAX):
                    sub = _deletion_filter(check, sub)
            log.info("conflict (%s, %d factors): %s", rel, len(sub), "; ".join(map(str, sub)))
            return Conflict(tuple(sub), rel), {}
    return None, values
