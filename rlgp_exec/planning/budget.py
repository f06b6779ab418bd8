"""The planners' budget: CPU time (not wall time) and memory, checked inside every stage.

Both papers report CPU time; a wall-clock budget on a shared machine measures its load (the same
planner, given fewer cycles, would try fewer candidates and fail more). Children count once they
have finished (Fast Downward runs as one).

A planner call opens one ``Budget`` (``using``); the stages below it find it in a context variable
and call ``check()`` in their loops (collision sweeps, IK solves, sampling, the symbolic search, between
NLP starts, IPOPT iterations through ``ipopt_stop``). A check reads the CPU clock (about a microsecond)
and, at most every ``MEMORY_EVERY_S`` of CPU time, the resident set size; past either limit it raises
``BudgetError``, which the planner turns into a failed Plan whose reason names the stage
("budget: 90 s CPU spent in keyframes of candidate 3"). Without an open budget a check does nothing.
The module imports nothing of the project but ``errors``: the layers below the planners (``reach``) check too.
"""

from __future__ import annotations

import contextvars
import logging
import os
import resource
from collections.abc import Iterator, Sequence
from contextlib import AbstractContextManager, contextmanager, nullcontext

import casadi as ca

from rlgp_exec.errors import RlgpError

__all__ = [
    "MEMORY_CAP_BYTES",
    "Budget",
    "BudgetError",
    "active",
    "check",
    "cpu_clock",
    "ipopt_stop",
    "left",
    "rss_bytes",
    "shared",
    "using",
]

log = logging.getLogger(__name__)
#: growth of the resident set over its size when the budget opened: the process stays far below the few GB
#: of a robot's computer (a plan of a shipped scene grows it by ~0.1-0.3 GB)
MEMORY_CAP_BYTES = 1536 * 2**20
MEMORY_EVERY_S = 0.05  # [s] CPU time between two reads of the resident set size (a read costs ~20 us)
_PAGE = os.sysconf("SC_PAGE_SIZE") if hasattr(os, "sysconf") else 4096


def cpu_clock() -> float:
    """CPU time [s] of this process and of its finished children (user + system)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def rss_bytes() -> int:
    """This process's resident set size [bytes] (its peak where /proc is missing)."""
    try:
        with open("/proc/self/statm", "rb") as f:
            return int(f.read().split()[1]) * _PAGE
    except (OSError, IndexError, ValueError):
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


class BudgetError(RlgpError):
    """A planner's budget ran out inside a stage (caught by the planner, which returns a failed Plan
    with this message as its reason)."""


class Budget:
    """``cpu_s`` [s] of CPU time (``cpu_clock``) and ``memory_bytes`` of resident-set growth from now, or
    what an enclosing budget (``active()`` when it is made: a caller's, round a planner call) has left
    if that is less. ``scope`` (e.g. "candidate 3") and ``stage`` (e.g. "keyframes") say where the
    planner is, for the reason."""

    def __init__(self, cpu_s: float, memory_bytes: int = MEMORY_CAP_BYTES) -> None:
        if not cpu_s > 0 or memory_bytes <= 0:
            raise RlgpError(f"Budget: need cpu_s > 0 and memory_bytes > 0, got {cpu_s}, {memory_bytes}")
        self.cpu_s, self.memory_bytes = float(cpu_s), int(memory_bytes)
        self.start = cpu_clock()
        self.deadline = self.start + self.cpu_s
        self.rss0 = rss_bytes()
        self._next_memory = self.start + MEMORY_EVERY_S
        self.scope, self.stage = "", "setup"
        outer = active()
        if outer is not None:
            if outer.deadline < self.deadline:  # the reason names the budget that binds
                self.deadline, self.cpu_s = outer.deadline, outer.cpu_s
            self.memory_bytes = min(self.memory_bytes, max(0, outer.memory_bytes - (self.rss0 - outer.rss0)))
        self._pid = os.getpid()  # the process whose clock ``deadline`` is on
        self._spent: str | None = None

    def left(self) -> float:
        """CPU time [s] left (negative once spent)."""
        return self.deadline - cpu_clock()

    def spent(self) -> float:
        return cpu_clock() - self.start

    def where(self) -> str:
        return f"{self.stage} of {self.scope}" if self.scope else self.stage

    def exhausted(self) -> str | None:
        """Why the budget is spent ("budget: ..."), or None while it holds; once spent, it stays spent."""
        if self._spent is not None:
            return self._spent
        now = cpu_clock()
        if now > self.deadline:
            self._spent = f"budget: {self.cpu_s:g} s CPU spent in {self.where()}"
        elif now >= self._next_memory:
            self._next_memory = now + MEMORY_EVERY_S
            grown = rss_bytes() - self.rss0
            if grown > self.memory_bytes:
                self._spent = (f"budget: memory grew by {grown / 2**20:.0f} MiB (cap {self.memory_bytes / 2**20:.0f} "
                               f"MiB) in {self.where()}")
        return self._spent

    def check(self) -> None:
        """Raise ``BudgetError`` once the budget is spent."""
        why = self.exhausted()
        if why is not None:
            log.info("%s (%.1f s CPU since the plan began)", why, self.spent())
            raise BudgetError(why)

    @contextmanager
    def at(self, stage: str, scope: str | None = None) -> Iterator[None]:
        """Name where the planner is while the block runs (``stage``, and ``scope`` if given)."""
        before = self.stage, self.scope
        self.stage = stage
        if scope is not None:
            self.scope = scope
        try:
            yield
        finally:
            self.stage, self.scope = before

    @contextmanager
    def shared(self, ways: int) -> Iterator[None]:
        """While the block runs, this process may spend 1/``ways`` of what is left: the rest is for forked
        children, whose CPU time the clock counts only once they have finished."""
        deadline = self.deadline
        self.deadline = cpu_clock() + max(0.0, deadline - cpu_clock()) / ways
        try:
            yield
        finally:
            self.deadline = deadline

    def forked(self, parent_clock: float) -> None:
        """In a child forked when the parent's ``cpu_clock`` read ``parent_clock``: the same CPU time left,
        counted on the child's own clock (which starts again at the fork), the memory from the child's size.
        Once per process (a pool's worker may run several jobs)."""
        if self._pid == os.getpid():
            return
        self._pid = os.getpid()
        self.deadline = cpu_clock() + (self.deadline - parent_clock)
        self.start = cpu_clock() - (parent_clock - self.start)
        self.rss0 = rss_bytes()
        self._next_memory = cpu_clock()


_ACTIVE: contextvars.ContextVar[Budget | None] = contextvars.ContextVar("rlgp_budget", default=None)


def active() -> Budget | None:
    """The budget the current planner call opened, if any."""
    return _ACTIVE.get()


@contextmanager
def using(budget: Budget) -> Iterator[Budget]:
    """Make ``budget`` the one ``check`` and ``left`` see while the block runs."""
    token = _ACTIVE.set(budget)
    try:
        yield budget
    finally:
        _ACTIVE.reset(token)


def check() -> None:
    """``Budget.check`` of the active budget; nothing without one."""
    b = _ACTIVE.get()
    if b is not None:
        b.check()


def shared(ways: int) -> AbstractContextManager[object]:
    """``Budget.shared`` of the active budget round work forked ``ways`` ways; nothing without one."""
    b = _ACTIVE.get()
    return nullcontext() if b is None else b.shared(ways)


def left(default: float = float("inf")) -> float:
    """CPU time [s] the active budget has left, ``default`` without one."""
    b = _ACTIVE.get()
    return default if b is None else b.left()


class _IpoptStop(ca.Callback):
    """IPOPT's iteration callback: asks it to stop (``User_Requested_Stop``) once the active budget is
    spent; the caller's next ``check()`` raises. Reads no iterate (its inputs are empty), so it is one
    object for every NLP."""

    def __init__(self) -> None:
        ca.Callback.__init__(self)
        self.construct("budget_stop", {})

    def get_n_in(self) -> int:
        return ca.nlpsol_n_out()

    def get_n_out(self) -> int:
        return 1

    def get_name_in(self, i: int) -> str:
        return ca.nlpsol_out(i)

    def get_name_out(self, i: int) -> str:
        return "ret"

    def get_sparsity_in(self, i: int) -> ca.Sparsity:
        return ca.Sparsity(0, 0)

    def eval(self, arg: Sequence[ca.DM]) -> list[int]:
        b = _ACTIVE.get()
        return [1 if b is not None and b.exhausted() is not None else 0]


_STOP: list[_IpoptStop] = []


def ipopt_stop() -> dict:
    """nlpsol options for an IPOPT solver whose iterations end once the active budget is spent."""
    if not _STOP:
        _STOP.append(_IpoptStop())
    return {"iteration_callback": _STOP[0], "iteration_callback_step": 5}
