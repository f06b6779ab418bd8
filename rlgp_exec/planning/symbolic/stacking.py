"""Stacking order for the symbolic search: which objects are where the goal wants them for good.

An object is *in place* when it rests on its goal support and that support is in place too (a fixture, a
region, or a movable object in place itself); an object without a goal is in place when what it rests on
is, unless that support must take another object (a slot or a movable object some goal stacks onto, or a
region some goal puts an object onto: a tower's base region is the tower's, whatever else fits; what the
goal puts there is in place only once those are cleared). Every
object not in place must still be picked and put down at least once (two actions), whatever the order, so
a tower's upper block stacked onto a lower one that is not yet on the goal counts as unfinished, and so
does anything resting on it: the count is a lower bound that knows a block goes down before the one on it
and that a block with something on it is cleared first.

Two prunings follow from it (``Stacking.prune``), for goals onto slots and movable objects only (goals onto
surfaces have ``relevance.without_detours``): an object in place is never picked up again, and an object
whose goal support is ready (clear and in place) is put nowhere else. Each removes only plans that a
shorter one with the same ordering of the other objects dominates. A third orders the clearing of a goal
region: nothing is set down on it while something without a goal stands there, and nothing without a goal
is set down on it (an object set down beside the clutter would have to fit between it, which the search
cannot tell; obstacles_tower_pr2's region holds its two obstacles and no more).
"""

from __future__ import annotations

from collections.abc import Sequence

from rlgp_exec.planning.actions import Kind
from rlgp_exec.planning.symbolic.model import GroundAction, GroundProblem, SymbolicState

__all__ = ["ONE_OBJECT", "Stacking", "supports"]

#: the support types that take one object, on top, only while clear
ONE_OBJECT = ("slot", "movable")
_PUT_DOWN = (Kind.PLACE, Kind.STACK)


def supports(state: SymbolicState) -> dict[str, str]:
    """object -> what it rests on, in ``state``."""
    return {a[1]: a[2] for a in state if a[0] == "on"}


class Stacking:
    """The goal's stacking structure of ``problem``: goal supports, the one-object supports some goal
    names, and the put-downs the grounded operators allow."""

    def __init__(self, problem: GroundProblem, regions: frozenset[str] | set[str] = frozenset()) -> None:
        self.types = dict(problem.objects)
        self.movable = frozenset(n for n, t in problem.objects if t == "movable")
        self.goal_on = {g[1]: g[2] for g in problem.goal if g[0] == "on" and len(g) == 3}
        self.in_goal = frozenset(g[1] for g in problem.goal if g[0] == "in")
        #: one-object supports a goal stacks onto: whatever else rests there must be cleared off
        self.wanted = {s: o for o, s in self.goal_on.items() if self.types.get(s) in ONE_OBJECT}
        #: regions (of ``regions``, the scene's) a goal puts an object onto: what has no goal there is cleared
        self.claimed = frozenset(s for s in self.goal_on.values() if s in regions)
        on0 = supports(problem.init)
        blocked = any(s in self.claimed and o not in self.goal_on for o, s in on0.items())
        # towers, Hanoi (goals onto slots or movable objects), a goal region something else stands on
        self.active = bool(self.wanted) or blocked
        self.put_downs = frozenset(
            (op.action.args[1], op.action.args[2]) for op in problem.operators if op.action.name in _PUT_DOWN
        )

    def in_place(self, on: dict[str, str]) -> dict[str, bool]:
        """For every movable object resting somewhere (``on``: ``supports(state)``), whether it is in place."""
        memo: dict[str, bool] = {}
        # goal regions something without a goal stands on: what the goal puts there waits until it is cleared
        cluttered = {s for o, s in on.items() if s in self.claimed and o not in self.goal_on}

        def placed(o: str, depth: int = 0) -> bool:
            if o in memo:
                return memo[o]
            s = on.get(o)
            if s is None or depth > len(on):  # held (or a cycle, which a state cannot have)
                ok = False
            elif o in self.goal_on:
                ok = s == self.goal_on[o] and (s not in self.movable or placed(s, depth + 1)) and s not in cluttered
            elif o in self.in_goal:
                ok = False
            else:  # no goal: fine unless its support must move, take another object, or is a goal region
                ok = (s not in self.movable or placed(s, depth + 1)) and s not in self.wanted and s not in self.claimed
            memo[o] = ok
            return ok

        for o in on:
            if o in self.movable:
                placed(o)
        return memo

    def unfinished(self, state: SymbolicState, counted: frozenset[str] | set[str]) -> list[str]:
        """The objects resting somewhere that are not in place and not in ``counted`` (the objects whose
        goal literals do not all hold yet, which ``heuristics.goal_lower_bound`` counts already)."""
        if not self.active:
            return []
        on = supports(state)
        return sorted(o for o, ok in self.in_place(on).items() if not ok and o not in counted)

    def ready(self, s: str, state: SymbolicState, placed: dict[str, bool]) -> bool:
        """Whether support ``s`` can take its goal object now: clear, and in place if it is an object."""
        return ("clear", s) in state and (s not in self.movable or placed.get(s, False))

    def prune(self, prefix: Sequence[GroundAction], state: SymbolicState) -> bool:
        """Whether the plan ``prefix`` (ending in the action that led to ``state``) is dominated (see the
        module docstring)."""
        if not self.active or not prefix:
            return False
        a = prefix[-1]
        if a.name not in (Kind.PICK, *_PUT_DOWN) or len(a.args) < 3:
            return False
        o, s = a.args[1], a.args[2]
        on = supports(state)
        cluttered = any(x not in self.goal_on and t == s for x, t in on.items())
        if a.name in _PUT_DOWN and s in self.claimed and (o not in self.goal_on or cluttered):
            return True  # nothing onto a goal region until it is cleared
        goal = self.goal_on.get(o)
        if goal is None or self.types.get(goal) not in ONE_OBJECT:
            return False
        placed = self.in_place(on)
        if a.name == Kind.PICK:  # it was in place before: the pick changed nothing below it
            return s == goal and (s not in self.movable or placed.get(s, False))
        return s != goal and (o, goal) in self.put_downs and self.ready(goal, state, placed)
