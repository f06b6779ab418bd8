"""Best-first symbolic search (R-LGP Algorithm 1, the symbolic layer) with a pluggable cost.

``best_first(problem, cost_fn, max_expansions)`` returns an iterator of candidate plans in order
of ``g + weight * heuristic`` where ``g`` accumulates ``cost_fn(actions_so_far, action)`` (R-LGP
plugs in its reachability-graph cost; :func:`unit_cost` and the distance-only baseline live in
``heuristics``). After a geometric failure the caller asks for ``next()`` and gets the next
candidate. A state may be reached on at most ``max_visits`` different paths (k-best search), paths
never revisit a state, and goal nodes are not expanded. With a consistent heuristic, ``weight=1``
and a state-independent cost the first plan is optimal.

A path-dependent cost whose heuristic needs the path too (where the hand is, where the objects moved)
is a :class:`PathCost`: each node carries the model's context, so a step costs O(1) in the plan's
length, and ``remaining(state, context)`` is the heuristic. ``weight > 1`` is weighted A*: the first
plan costs at most ``weight`` times the optimum when ``remaining`` is admissible, found in far fewer
expansions.
"""

from __future__ import annotations

import heapq
import itertools
import logging
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from rlgp_exec.planning import budget
from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.model import GroundAction, GroundProblem, SymbolicState

__all__ = [
    "BestFirst", "CandidatePlan", "CostFn", "Heuristic", "PathCost", "SearchStats", "best_first", "unit_cost",
]

log = logging.getLogger(__name__)

#: cost of appending ``action`` to the plan prefix ``actions`` (>= 0)
CostFn = Callable[[Sequence[GroundAction], GroundAction], float]
#: estimated remaining cost of a state (>= 0)
Heuristic = Callable[[SymbolicState], float]


class PathCost(Protocol):
    """A path-dependent cost with its heuristic; the context is the model's own (immutable) value."""

    def start(self) -> Any:
        """The context of the empty plan."""
        ...

    def step(self, context: Any, action: GroundAction) -> tuple[float, Any]:
        """The cost (>= 0) of appending ``action`` to the plan that ``context`` describes, and the new context."""
        ...

    def remaining(self, state: SymbolicState, context: Any) -> float:
        """An estimate (>= 0) of the cost still needed from ``state`` reached as ``context`` says."""
        ...


def unit_cost(actions: Sequence[GroundAction], action: GroundAction) -> float:
    """Every action costs 1: plans in order of length."""
    return 1.0


@dataclass
class SearchStats:
    expanded: int = 0  # nodes whose successors were generated
    generated: int = 0  # successor nodes pushed on the frontier
    plans: int = 0  # candidate plans returned so far
    exhausted: bool = False  # the frontier ran empty: no further plan exists
    budget_hit: bool = False  # stopped at max_expansions


@dataclass(frozen=True)
class CandidatePlan:
    actions: tuple[GroundAction, ...]
    cost: float  # sum of cost_fn along the plan
    states: tuple[SymbolicState, ...]  # init ... goal state, len(actions) + 1

    def __str__(self) -> str:
        return " ".join(str(a) for a in self.actions)


class _Node:
    __slots__ = ("action", "context", "depth", "g", "parent", "state")

    def __init__(
        self, state: SymbolicState, action: GroundAction | None, parent: _Node | None, g: float, context: Any = None,
    ) -> None:
        self.state = state
        self.action = action
        self.parent = parent
        self.g = g
        self.context = context
        self.depth: int = 0 if parent is None else parent.depth + 1

    def actions(self) -> list[GroundAction]:
        out: list[GroundAction] = []
        n: _Node | None = self
        while n is not None and n.action is not None:
            out.append(n.action)
            n = n.parent
        return out[::-1]

    def states(self) -> list[SymbolicState]:
        out: list[SymbolicState] = []
        n: _Node | None = self
        while n is not None:
            out.append(n.state)
            n = n.parent
        return out[::-1]

    def on_path(self, state: SymbolicState) -> bool:
        n: _Node | None = self
        while n is not None:
            if n.state == state:
                return True
            n = n.parent
        return False


class BestFirst(Iterator[CandidatePlan]):
    """The search as an iterator of :class:`CandidatePlan`; ``stats`` counts its work."""

    def __init__(
        self,
        problem: GroundProblem,
        cost_fn: CostFn = unit_cost,
        max_expansions: int = 100_000,
        heuristic: Heuristic | None = None,
        weight: float = 1.0,
        max_visits: int = 4,
        prune: Callable[[Sequence[GroundAction], SymbolicState], bool] | None = None,
        model: PathCost | None = None,
    ) -> None:
        if max_expansions < 1 or max_visits < 1 or weight < 0:
            raise SymbolicError(
                f"best_first: need max_expansions >= 1, max_visits >= 1, weight >= 0; "
                f"got {max_expansions}, {max_visits}, {weight}"
            )
        self.problem = problem
        self.cost_fn = cost_fn
        self.max_expansions = max_expansions
        self.heuristic = heuristic
        self.weight = weight
        self.max_visits = max_visits
        self.prune = prune
        self.model = model
        self.stats = SearchStats()
        self._visits: dict[SymbolicState, int] = {}
        self._tie = itertools.count()
        self._frontier: list[tuple[float, float, int, _Node]] = []
        self._forbidden: set[tuple[GroundAction, ...]] = set()
        self._forbidden_lengths: set[int] = set()
        self._push(_Node(problem.init, None, None, 0.0, model.start() if model is not None else None))

    def _push(self, node: _Node) -> None:
        if self.model is not None:
            h = self.model.remaining(node.state, node.context)
        else:
            h = self.heuristic(node.state) if self.heuristic is not None else 0.0
        heapq.heappush(self._frontier, (node.g + self.weight * h, h, next(self._tie), node))

    def __iter__(self) -> BestFirst:
        return self

    def forbid(self, prefix: Sequence[GroundAction]) -> None:
        """Drop every further plan that begins with ``prefix`` (one the geometry cannot realise, whatever
        follows): the frontier's nodes below it are skipped when they come up."""
        if prefix:
            self._forbidden.add(tuple(prefix))
            self._forbidden_lengths.add(len(prefix))

    def _is_forbidden(self, node: _Node) -> bool:
        lengths = [n for n in self._forbidden_lengths if n <= node.depth]
        if not lengths:
            return False
        actions = tuple(node.actions())
        return any(actions[:n] in self._forbidden for n in lengths)

    def __next__(self) -> CandidatePlan:
        problem = self.problem
        while self._frontier:
            _, _, _, node = heapq.heappop(self._frontier)
            seen = self._visits.get(node.state, 0)
            if seen >= self.max_visits or (self._forbidden and self._is_forbidden(node)):
                continue
            self._visits[node.state] = seen + 1
            if problem.is_goal(node.state):
                self.stats.plans += 1
                plan = CandidatePlan(tuple(node.actions()), node.g, tuple(node.states()))
                log.debug(
                    "candidate %d (cost %.3f, %d expanded): %s", self.stats.plans, plan.cost, self.stats.expanded, plan
                )
                return plan
            if self.stats.expanded >= self.max_expansions:
                self.stats.budget_hit = True
                log.info("best_first %s: stopped at max_expansions=%d", problem.name, self.max_expansions)
                raise StopIteration
            self.stats.expanded += 1
            if not self.stats.expanded & 255:
                budget.check()
            prefix: list[GroundAction] | None = None
            for action, succ in problem.successors(node.state):
                if self._visits.get(succ, 0) >= self.max_visits or node.on_path(succ):
                    continue
                if self.prune is not None or self.model is None:
                    if prefix is None:
                        prefix = node.actions()
                    if self.prune is not None and self.prune([*prefix, action], succ):
                        continue
                context = None
                if self.model is not None:
                    step, context = self.model.step(node.context, action)
                else:
                    assert prefix is not None
                    step = self.cost_fn(prefix, action)
                if step < 0:
                    raise SymbolicError(f"best_first: cost returned {step} < 0 for {action}")
                self.stats.generated += 1
                self._push(_Node(succ, action, node, node.g + step, context))
        self.stats.exhausted = True
        raise StopIteration


def best_first(
    problem: GroundProblem,
    cost_fn: CostFn = unit_cost,
    max_expansions: int = 100_000,
    *,
    heuristic: Heuristic | None = None,
    weight: float = 1.0,
    max_visits: int = 4,
    prune: Callable[[Sequence[GroundAction], SymbolicState], bool] | None = None,
    model: PathCost | None = None,
) -> BestFirst:
    """Candidate plans of ``problem`` in order of cost (see the module docstring).

    ``heuristic`` guides the search (e.g. ``heuristics.goal_lower_bound(problem)``, admissible);
    ``prune(prefix, state)`` drops a node (e.g. a forbidden partial plan, ``reformulate``); the
    iterator stops when no plan is left (``stats.exhausted``) or at ``max_expansions``
    (``stats.budget_hit``). ``model`` (a :class:`PathCost`) replaces ``cost_fn`` and ``heuristic``.
    """
    return BestFirst(problem, cost_fn, max_expansions, heuristic, weight, max_visits, prune, model)
