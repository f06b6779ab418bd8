"""Real-time scheduling for a fixed-rate control loop: what a robot's controller process asks of Linux.

A 100 Hz loop in Python misses its deadlines by milliseconds when other work shares the cores (a renderer,
tag detection, a planner) and when another thread of the same process holds the GIL. Two things fix that:

* the loop's own thread runs under ``SCHED_FIFO`` (as ros2_control's controller manager does), so the
  kernel wakes it ahead of every normal process; granted to root, ``CAP_SYS_NICE`` or an ``rtprio``
  limit (``/etc/security/limits.conf``), else the loop keeps its normal priority and says why once
  (``RLGP_EXEC_REALTIME=0`` turns it off);
* the interpreter's GIL switch interval is shortened, so a busy Python thread hands the GIL to the
  woken loop within 0.1 ms rather than 5 ms.

:func:`sleep_until` sleeps to an absolute deadline and spins its last fraction of a millisecond (the OS
wakes a sleeper late by up to ~1 ms).
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NamedTuple

__all__ = [
    "ENV_SWITCH",
    "RT_PRIORITY",
    "SPIN_S",
    "RealtimeGrant",
    "realtime_priority",
    "request_realtime",
    "sleep_until",
]

log = logging.getLogger(__name__)

RT_PRIORITY = 40  # below the kernel's own RT threads (50) and ros2_control's default (50)
SWITCH_INTERVAL_S = 0.0001  # [s] the GIL switch interval while a loop runs (CPython's default is 5 ms)
ENV_SWITCH = "RLGP_EXEC_REALTIME"  # "0": no SCHED_FIFO for any loop of this process or its children
SPIN_S = 0.0008  # [s] the last part of a wait that is spun rather than slept

_warned = threading.Lock()
_said_no = False


class RealtimeGrant(NamedTuple):
    granted: bool
    policy: str  # "SCHED_FIFO <priority>" or "SCHED_OTHER"
    reason: str  # why not, when not granted; "" otherwise


def request_realtime(priority: int = RT_PRIORITY) -> RealtimeGrant:
    """Put the calling thread under ``SCHED_FIFO`` at ``priority`` and shorten the GIL switch interval.

    Never raises: a refusal (no permission, not Linux) is returned, and logged once per process."""
    global _said_no
    sys.setswitchinterval(min(sys.getswitchinterval(), SWITCH_INTERVAL_S))
    if os.environ.get(ENV_SWITCH, "1") == "0":
        return RealtimeGrant(False, "SCHED_OTHER", f"{ENV_SWITCH}=0")
    if not hasattr(os, "sched_setscheduler"):
        grant = RealtimeGrant(False, "SCHED_OTHER", f"no SCHED_FIFO on {sys.platform}")
    else:
        try:
            os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(priority))  # 0: this thread
            return RealtimeGrant(True, f"SCHED_FIFO {priority}", "")
        except (PermissionError, OSError) as e:
            grant = RealtimeGrant(
                False,
                "SCHED_OTHER",
                f"SCHED_FIFO refused ({e.strerror or e}): run as root, with CAP_SYS_NICE, or with an rtprio limit",
            )
    with _warned:
        if not _said_no:
            _said_no = True
            log.warning("control loop at normal priority: %s; its period may slip by milliseconds", grant.reason)
    return grant


def _normal() -> None:
    if hasattr(os, "sched_setscheduler"):
        with contextlib.suppress(OSError):  # dropping a priority is always allowed
            os.sched_setscheduler(0, os.SCHED_OTHER, os.sched_param(0))


@contextmanager
def realtime_priority(enabled: bool = True, priority: int = RT_PRIORITY) -> Iterator[RealtimeGrant]:
    """``SCHED_FIFO`` for the calling thread inside the block (the control loop), normal priority after
    (planning between motions must not preempt the rest of the machine)."""
    if not enabled:
        yield RealtimeGrant(False, "SCHED_OTHER", "not requested")
        return
    grant = request_realtime(priority)
    try:
        yield grant
    finally:
        if grant.granted:
            _normal()


def sleep_until(deadline: float, stop: threading.Event | None = None) -> None:
    """Wait until ``time.perf_counter() >= deadline``: sleep, then spin the last :data:`SPIN_S`.
    With ``stop``, its setting ends the sleep early (the spin is too short to matter)."""
    delay = deadline - time.perf_counter()
    if delay > SPIN_S:
        if stop is not None:
            if stop.wait(delay - SPIN_S):
                return
        else:
            time.sleep(delay - SPIN_S)
    while time.perf_counter() < deadline:
        pass
