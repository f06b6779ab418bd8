"""The simulated robot's fixed-rate loop: a thread that calls its tick at absolute deadlines and keeps the
period errors it saw (the robot servers' 100 Hz, Zenoh and CAN alike). Asked to (a robot PC of its own), it
runs under ``SCHED_FIFO`` where the OS allows (:mod:`rlgp_exec.hal.realtime`). Not by default: beside the
executive it stands in for a robot to, its thread under ``SCHED_FIFO`` starves the server's own message
threads, and the setpoints it is sent queue up behind it."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from rlgp_exec.hal.realtime import RealtimeGrant, request_realtime, sleep_until

__all__ = ["RealTimeLoop"]

log = logging.getLogger(__name__)


class RealTimeLoop:
    """Call ``tick()`` every ``period`` s on absolute deadlines (no drift); records the period errors."""

    def __init__(self, period: float, tick: Callable[[], None], name: str = "loop", realtime: bool = False) -> None:
        self.period = period
        self.realtime = realtime  # the loop's thread under SCHED_FIFO when the OS allows it
        self.grant = RealtimeGrant(False, "SCHED_OTHER", "not started")
        self.tick = tick
        self.name = name
        self.errors_ms: list[float] = []  # |actual period - nominal| per cycle, last 10 000
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self.run, name=self.name, daemon=True)
        self._thread.start()

    def run(self) -> None:
        if self.realtime:
            self.grant = request_realtime()
        nxt = time.perf_counter()
        last = nxt
        while not self._stop.is_set():
            try:
                self.tick()
            except Exception:  # a bug in one tick must not kill the robot's loop silently
                log.exception("%s: tick failed", self.name)
            nxt += self.period
            now = time.perf_counter()
            if now - nxt > 5 * self.period:  # fell far behind (machine stalled): resynchronise
                nxt = now
            sleep_until(nxt, self._stop)
            t = time.perf_counter()
            self.errors_ms.append(abs((t - last) - self.period) * 1e3)
            if len(self.errors_ms) > 10_000:
                del self.errors_ms[:5_000]
            last = t

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def p99_ms(self) -> float:
        return float(np.percentile(self.errors_ms, 99)) if self.errors_ms else float("nan")
