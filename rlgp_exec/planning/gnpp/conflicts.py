"""Finding a small infeasible subgraph (GNPP paper, Sec. VI and Alg. 1 of the appendix).

For each relaxation in order (loose to tight) the relaxed graph is split into connected components;
each component is solved (at the tightest relaxations tried whole first, ``WHOLE_FIRST``); the first
infeasible one is cut down by the double binary search on the time index, then (``convergence``) to
the factors violated at the optimizer's convergence point if those alone are infeasible, and finally
by QuickXplain (divide and conquer over the factors) so that the conflict is minimal (Def. 4.4):
infeasible, and feasible without any one of its factors.
Every solve goes through ``Checker`` (counts, optional database).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, replace

from rlgp_exec.planning import budget
from rlgp_exec.planning.gnpp.database import SubgraphDB
from rlgp_exec.planning.gnpp.graph import PAPER_ORDER, Relaxation, components, relax, time_slice, times_of
from rlgp_exec.planning.gnpp.pntc import Factor, Var
from rlgp_exec.planning.gnpp.solver import RESTART_ABOVE, Feasibility, GraphSolver, SolveResult
from rlgp_exec.planning.margins import FEAS_TOL
from rlgp_exec.robot.model import FloatArray

__all__ = ["Checker", "Conflict", "ExtractOptions", "find_conflict"]

log = logging.getLogger(__name__)
FILTER_MAX = RESTART_ABOVE  # conflicts up to this size are made minimal (QuickXplain) and refuted
#: relaxations whose components are tried whole before the time search: the tightest ones (arms and
#: their collisions), where the NLPs are large and nearly always feasible once the looser relaxations
#: are, so a window-by-window search would cost several growing solves for the same verdict
WHOLE_FIRST = (Relaxation.NO_TIME, Relaxation.NONE)
#: relaxations whose large NLPs found infeasible from the guess get ``GraphSolver``'s second start (the
#: arms' start postures, ``solver.RESTART_ABOVE``): the full graph only, where it turns verdicts; at "No
#: Time" it never did and cost seconds
RESTARTED = (Relaxation.NONE,)
FILTER_MAX_NO_ROBOT = 200  # ... or this size when no factor has an arm variable (object poses only)


@dataclass(frozen=True)
class ExtractOptions:
    time_search: bool = True  # t
    relaxations: bool = True  # r
    convergence: bool = True  # n (with QuickXplain)
    database: bool = False  # g


@dataclass(frozen=True)
class Conflict:
    factors: tuple[Factor, ...]
    relaxation: Relaxation

    def __str__(self) -> str:
        return " ; ".join(str(f) for f in self.factors)


class Checker:
    """Feasibility of subgraphs: the database first (if any), else an NLP solve (counted); raises
    ``budget.BudgetError`` before a solve once the active budget is spent. A subgraph asked about again
    within one plan's check is answered from the earlier solve (the time search, the convergence step
    and QuickXplain revisit the same windows); ``last`` is that solve's result either way."""

    def __init__(
        self,
        solver: GraphSolver,
        guess: Mapping[Var, FloatArray],
        db: SubgraphDB | None = None,
    ) -> None:
        self.solver, self.guess, self.db = solver, dict(guess), db
        self.last: SolveResult | None = None
        self.restart = True  # a large NLP found infeasible gets the solver's second start (``RESTARTED``)
        self._seen: dict[frozenset[Factor], tuple[tuple[Factor, ...], SolveResult]] = {}

    def feasible(self, factors: Sequence[Factor], tentative: bool = False) -> bool:
        """``tentative``: one start (no second start from the arms' start postures), and only a
        "feasible" answer counts: an "infeasible" one is neither remembered nor put in the database
        (the caller asks smaller questions next, and may ask this one again from a better guess)."""
        self.last = None
        if not factors:
            return True
        seen = self._seen.get(frozenset(factors))
        if seen is not None:
            order, res = seen
            if tuple(factors) != order:  # the violations in the order asked
                viol = dict(zip(order, res.violations, strict=True))
                res = replace(res, violations=tuple(viol[f] for f in factors))
            self.last = res
            return res.feasible
        budget.check()
        if self.db is not None:
            known = self.db.lookup(factors)
            if known is not None:
                return known
        restarts = self.solver.restarts
        self.solver.restarts = 0 if tentative or not self.restart else restarts
        try:
            res = self.solver.solve(factors, self.guess)
        finally:
            self.solver.restarts = restarts
        self.last = res
        if tentative and not res.feasible:
            return False
        self._seen[frozenset(factors)] = (tuple(factors), res)
        if self.db is not None:
            self.db.add(factors, res.feasible)
        return res.feasible

    def proven_feasible(self, factors: Sequence[Factor], values: Mapping[Var, FloatArray]) -> None:
        """``factors`` has the feasible point ``values`` (found from another start): remembered as
        feasible, so the search asked again does not return it as a conflict."""
        res = SolveResult(Feasibility.FEASIBLE, dict(values), (0.0,) * len(factors), 0.0)
        self._seen[frozenset(factors)] = (tuple(factors), res)

    def forget_infeasible(self) -> None:
        """Drop the remembered "infeasible" answers (once a conflict was refuted from another start
        and the guess moved: they are asked again from the new guess); "feasible" stays proven."""
        self._seen = {k: v for k, v in self._seen.items() if v[1].feasible}


def _keep(check: Checker) -> None:
    """A feasible window's solution warm-starts the larger windows after it."""
    if check.last is not None:
        check.guess.update(check.last.values)


def _time_search(check: Checker, g: list[Factor], coarse: bool = False, whole: bool = False) -> list[Factor] | None:
    """The minimal time window [f, l] of a component, or None if the component is feasible (then
    ``check.last`` is the solve of all of it). Double search on the time index (Sec. VI-A), galloping:
    the smallest l with G[t0 .. l] infeasible is bracketed by windows of 1, 2, 4, ... steps from t0,
    then bisected; likewise the largest f with G[f .. l] infeasible, with windows growing back from l.
    Small feasible windows are cheap and warm-start the next ones; an infeasible verdict is the
    expensive kind (the solver runs to its limits), and this way the infeasible windows solved are
    the smallest ones, not the whole component first (the paper's "numerous small and feasible
    problems first"). ``whole``: the component is tried whole first, tentatively (one start; an
    "infeasible" answer is no verdict and is asked again window by window)."""
    t0, t1 = times_of(g)
    if whole and check.feasible(g, tentative=True):
        return None
    lo, hi, n = t0, None, 1  # G[t0 .. lo-1] is feasible; G[t0 .. hi] is infeasible
    while hi is None:
        last = min(t0 + n - 1, t1)
        if check.feasible(time_slice(g, t0, last)):
            if last == t1:
                return None
            _keep(check)
            lo = last + 1
            n *= 2
        else:
            hi = last
    if hi > lo and check.last is not None:
        # the convergence point (Sec. VI-C) of the first infeasible window: the time span of the factors
        # violated there is one more window to try; if it is infeasible the search goes on inside it,
        # which skips the bisection's largest (slowest) infeasible windows
        window = time_slice(g, t0, hi)
        bad = [f for f, v in zip(window, check.last.violations, strict=True) if v > FEAS_TOL]
        if bad:
            a, b = times_of(bad)
            if (a, b) != (t0, hi) and not check.feasible(time_slice(g, a, b)):
                return _time_search(check, time_slice(g, a, b), coarse) or time_slice(g, a, b)
    if coarse and len(time_slice(g, t0, hi)) > FILTER_MAX:
        return time_slice(g, t0, hi)  # no bisection through windows of this size (see find_conflict)
    while lo < hi:
        mid = (lo + hi) // 2
        if check.feasible(time_slice(g, t0, mid)):
            _keep(check)
            lo = mid + 1
        else:
            hi = mid
    last = hi
    lo, hi, n = last + 1, t0, 1  # G[lo .. last] is feasible (empty at first); G[hi .. last] is infeasible
    while True:
        first = max(last - n + 1, t0)
        if first == t0 or not check.feasible(time_slice(g, first, last)):
            hi = first
            break
        lo = first
        n *= 2
    while hi + 1 < lo:  # the largest f in [hi, lo - 1] with G[f .. last] infeasible
        mid = (hi + lo) // 2
        if check.feasible(time_slice(g, mid, last)):
            lo = mid
        else:
            hi = mid
    log.debug("time window [%d, %d] of [%d, %d]", hi, last, t0, t1)
    return time_slice(g, hi, last)


def _convergence(check: Checker, g: list[Factor]) -> list[Factor]:
    """The factors violated at the convergence point, if they alone are infeasible (Sec. VI-C), else
    those with the factors over their variables only, if that is infeasible; else ``g``."""
    if check.feasible(g) or check.last is None:
        return g
    violated = [f for f, v in zip(g, check.last.violations, strict=True) if v > FEAS_TOL]
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


def _quickxplain(check: Checker, g: list[Factor]) -> list[Factor]:
    """A minimal infeasible subset of the infeasible ``g`` (Def. 4.4) by divide and conquer (Junker's
    QuickXplain, the paper's ref. [27]): O(k log(n/k)) checks for a conflict of k of n factors, where a
    deletion filter needs n, each of the n - k deletions that stay infeasible an expensive verdict.
    Halves are split in time order, so they stay local. (Being minimal, it is connected: Prop. 4.5.)"""
    pos = {f: i for i, f in enumerate(g)}

    def qx(base: list[Factor], delta: bool, cand: list[Factor]) -> list[Factor]:
        if delta and not check.feasible(base):
            return []
        if len(cand) == 1:
            return cand
        k = len(cand) // 2
        c1, c2 = cand[:k], cand[k:]
        d2 = qx(base + c1, True, c2)
        d1 = qx(base + d2, bool(d2), c1)
        return d1 + d2

    return sorted(qx([], False, list(g)), key=pos.__getitem__)


def find_conflict(
    check: Checker, graph: Sequence[Factor], opts: ExtractOptions
) -> tuple[Conflict | None, dict[Var, FloatArray]]:
    """(a small infeasible subgraph, or None and the convergence point of the full graph)."""
    order = PAPER_ORDER if opts.relaxations else (Relaxation.NONE,)
    try:
        return _find(check, graph, opts, order)
    finally:
        check.restart = True


def _find(
    check: Checker, graph: Sequence[Factor], opts: ExtractOptions, order: Sequence[Relaxation]
) -> tuple[Conflict | None, dict[Var, FloatArray]]:
    values: dict[Var, FloatArray] = {}
    for rel in order:
        check.restart = rel in RESTARTED
        for comp in components(relax(graph, rel)):
            # the full graph (every relaxation feasible): its windows are whole stretches of the plan,
            # each infeasible verdict the slowest kind; with the convergence heuristic, a window it
            # cannot cut below FILTER_MAX is not bisected further (the planner then blocks the plan)
            coarse = rel is Relaxation.NONE and opts.convergence
            if opts.time_search:
                window = _time_search(check, comp, coarse, whole=rel in WHOLE_FIRST)
            else:
                window = None if check.feasible(comp) else comp
            if window is None:
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
            sub = window
            if opts.convergence:
                sub = _convergence(check, sub)
                # larger ones stay as found (small, not proven minimal); without arms the NLPs are tiny
                if len(sub) <= (FILTER_MAX_NO_ROBOT if not any(f.robot for f in sub) else FILTER_MAX):
                    sub = _quickxplain(check, sub)
            log.info("conflict (%s, %d factors): %s", rel, len(sub), "; ".join(map(str, sub)))
            return Conflict(tuple(sub), rel), {}
    return None, values
