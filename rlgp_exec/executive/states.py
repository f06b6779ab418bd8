"""The executive's state machine: explicit states, the allowed transitions, and a log of every one.

::

    IDLE -> SENSING -> PLANNING -> EXECUTING -> SENSING (verify) -> IDLE
    EXECUTING -> RECOVERING (safe stop, then replan) -> SENSING | FAULT
    SENSING -> RECOVERING (let go of a drawer's knob: a motion of its own) -> SENSING
    any -> ESTOPPED (latched) --rearm (operator)--> IDLE
    any -> FAULT (latched) --reset (operator)--> IDLE

ESTOPPED and FAULT are latched: only an operator's request (``release``) leaves them, never the task that
was running when they latched. Every (state, target) pair is defined: a transition the table allows, a
no-op to the same state, or :class:`IllegalTransitionError`, which says whether the machine was pre-empted by a
latch (``preempted``: an expected race with an e-stop or a fault) or was asked for a transition that is a
bug in the caller. Every transition is logged and handed to the listeners (the recorder, the daemon's status
publisher).
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass

from rlgp_exec.errors import RlgpError

__all__ = ["LATCHED", "ExecState", "IllegalTransitionError", "StateMachine", "Transition"]

log = logging.getLogger(__name__)


class ExecState(enum.Enum):
    IDLE = "idle"
    SENSING = "sensing"
    PLANNING = "planning"
    EXECUTING = "executing"
    RECOVERING = "recovering"
    ESTOPPED = "estopped"
    FAULT = "fault"


S = ExecState
HISTORY = 10_000  # transitions kept in memory (every one is also recorded and published)
LATCHED = frozenset({S.ESTOPPED, S.FAULT})
_ALLOWED: dict[ExecState, frozenset[ExecState]] = {
    S.IDLE: frozenset({S.SENSING, S.ESTOPPED, S.FAULT}),
    S.SENSING: frozenset({S.PLANNING, S.IDLE, S.RECOVERING, S.ESTOPPED, S.FAULT}),
    S.PLANNING: frozenset({S.EXECUTING, S.IDLE, S.ESTOPPED, S.FAULT}),
    S.EXECUTING: frozenset({S.SENSING, S.RECOVERING, S.IDLE, S.ESTOPPED, S.FAULT}),
    S.RECOVERING: frozenset({S.SENSING, S.IDLE, S.ESTOPPED, S.FAULT}),
    S.ESTOPPED: frozenset({S.FAULT}),
    S.FAULT: frozenset({S.ESTOPPED}),
}
#: what an operator's request may do from a latched state (rearm, reset)
_RELEASE: dict[ExecState, frozenset[ExecState]] = {
    S.ESTOPPED: frozenset({S.IDLE}),
    S.FAULT: frozenset({S.IDLE}),
}


class IllegalTransitionError(RlgpError):
    """A transition the table does not allow. ``preempted``: the machine was latched (ESTOPPED, FAULT) by
    another request meanwhile, which the caller handles as that latch; otherwise a bug in the caller."""

    def __init__(self, source: ExecState, target: ExecState) -> None:
        self.source, self.target = source, target
        self.preempted = source in LATCHED
        valid = sorted(s.name for s in _ALLOWED[source])
        how = f"; {source.name} is latched: only an operator's request leaves it" if self.preempted else ""
        super().__init__(
            f"executive: no transition {source.name} -> {target.name}; valid from {source.name}: {valid}{how}"
        )


@dataclass(frozen=True)
class Transition:
    t_wall: float  # [s] time.time()
    source: ExecState
    target: ExecState
    reason: str

    def as_dict(self) -> dict[str, object]:
        return {"t_wall": self.t_wall, "from": self.source.value, "to": self.target.value, "reason": self.reason}


def allowed(source: ExecState, target: ExecState, *, operator: bool = False) -> bool:
    """Whether ``source -> target`` is a transition (``operator``: by an operator's release request)."""
    return target is source or target in _ALLOWED[source] or (operator and target in _RELEASE.get(source, ()))


class StateMachine:
    """The current state, guarded transitions, and listeners called on every transition (thread-safe)."""

    def __init__(self) -> None:
        self._state = ExecState.IDLE
        self._lock = threading.Lock()
        self.history: deque[Transition] = deque(maxlen=HISTORY)  # bounded: a daemon runs for months
        self.listeners: list[Callable[[Transition], None]] = []

    @property
    def state(self) -> ExecState:
        return self._state

    @property
    def reason(self) -> str:
        """Why the machine is in its state (the last transition's reason; '' at start)."""
        return self.history[-1].reason if self.history else ""

    def to(self, target: ExecState, reason: str = "") -> Transition:
        """Go to ``target``; :class:`IllegalTransitionError` if the table does not allow it."""
        return self._go(target, reason, operator=False)

    def release(self, target: ExecState, reason: str) -> Transition:
        """An operator's request out of a latched state (rearm, reset)."""
        return self._go(target, reason, operator=True)

    def settle(self, target: ExecState, reason: str = "") -> ExecState:
        """Go to ``target`` unless the machine is latched (then stay); the state afterwards. Atomic: an
        e-stop arriving from another thread is never overwritten."""
        with self._lock:
            if self._state in LATCHED and target not in _ALLOWED[self._state]:
                return self._state
        try:
            self.to(target, reason)
        except IllegalTransitionError as e:
            if not e.preempted:
                raise
        return self._state

    def _go(self, target: ExecState, reason: str, *, operator: bool) -> Transition:
        with self._lock:
            source = self._state
            if target is source:
                return Transition(time.time(), source, target, reason)
            if not allowed(source, target, operator=operator):
                raise IllegalTransitionError(source, target)
            self._state = target
            tr = Transition(time.time(), source, target, reason)
            self.history.append(tr)
        log.log(
            logging.WARNING if target in (S.FAULT, S.ESTOPPED, S.RECOVERING) else logging.INFO,
            "executive: %s -> %s%s",
            source.name,
            target.name,
            f" ({reason})" if reason else "",
        )
        for fn in list(self.listeners):
            try:
                fn(tr)
            except Exception:  # a listener never takes the executive down
                log.exception("executive: transition listener failed")
        return tr
