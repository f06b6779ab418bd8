"""The executive's state machine: explicit states, the allowed transitions, and a log of every one.

::

    IDLE -> SENSING -> PLANNING -> EXECUTING -> SENSING (verify) -> IDLE
    EXECUTING -> RECOVERING (safe stop, then replan) -> SENSING | FAULT
    SENSING -> RECOVERING (let go of a drawer's knob: a motion of its own) -> SENSING
    any -> ESTOPPED (latched) --rearm--> IDLE
    any -> FAULT --reset--> IDLE

A transition not in the table is a bug in the caller and raises; every transition is logged and handed
to the listeners (the recorder, the daemon's status publisher).
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

from rlgp_exec.errors import RlgpError

__all__ = ["ExecState", "StateMachine", "Transition"]

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
_ALLOWED: dict[ExecState, frozenset[ExecState]] = {
    S.IDLE: frozenset({S.SENSING, S.ESTOPPED, S.FAULT}),
    S.SENSING: frozenset({S.PLANNING, S.IDLE, S.RECOVERING, S.ESTOPPED, S.FAULT}),
    S.PLANNING: frozenset({S.EXECUTING, S.IDLE, S.ESTOPPED, S.FAULT}),
    S.EXECUTING: frozenset({S.SENSING, S.RECOVERING, S.IDLE, S.ESTOPPED, S.FAULT}),
    S.RECOVERING: frozenset({S.SENSING, S.IDLE, S.ESTOPPED, S.FAULT}),
    S.ESTOPPED: frozenset({S.IDLE, S.FAULT}),
    S.FAULT: frozenset({S.IDLE, S.ESTOPPED}),
}


@dataclass(frozen=True)
class Transition:
    t_wall: float  # [s] time.time()
    source: ExecState
    target: ExecState
    reason: str

    def as_dict(self) -> dict[str, object]:
        return {"t_wall": self.t_wall, "from": self.source.value, "to": self.target.value, "reason": self.reason}


class StateMachine:
    """The current state, guarded transitions, and listeners called on every transition (thread-safe)."""

    def __init__(self) -> None:
        self._state = ExecState.IDLE
        self._lock = threading.Lock()
        self.history: list[Transition] = []
        self.listeners: list[Callable[[Transition], None]] = []

    @property
    def state(self) -> ExecState:
        return self._state

    def to(self, target: ExecState, reason: str = "") -> Transition:
        with self._lock:
            source = self._state
            if target is source:
                tr = Transition(time.time(), source, target, reason)
                return tr
            if target not in _ALLOWED[source]:
                raise RlgpError(
                    f"executive: no transition {source.name} -> {target.name}; "
                    f"valid from {source.name}: {sorted(s.name for s in _ALLOWED[source])}"
                )
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
