"""The control loops' scheduling (rlgp_exec/hal/realtime.py): SCHED_FIFO inside the loop only, deadlines kept."""

from __future__ import annotations

import os
import sys
import threading
import time

import pytest

from rlgp_exec.hal.realtime import SPIN_S, realtime_priority, request_realtime, sleep_until

linux = pytest.mark.skipif(not hasattr(os, "sched_getscheduler"), reason="scheduling policies are Linux's")


@linux
def test_the_loop_thread_is_real_time_inside_the_block_and_normal_after():
    def in_thread(out: list[object]) -> None:
        with realtime_priority() as grant:
            out.append((grant, os.sched_getscheduler(0)))
        out.append(os.sched_getscheduler(0))

    out: list[object] = []
    t = threading.Thread(target=in_thread, args=(out,))
    t.start()
    t.join()
    (grant, inside), after = out
    assert after == os.SCHED_OTHER  # planning after a motion runs at normal priority
    if grant.granted:
        assert inside == os.SCHED_FIFO and grant.policy.startswith("SCHED_FIFO")
    else:  # no permission here: said why, and nothing changed
        assert inside == os.SCHED_OTHER and "SCHED_FIFO" in grant.reason
    assert os.sched_getscheduler(0) == os.SCHED_OTHER  # the test's own thread was never touched
    assert sys.getswitchinterval() <= 0.0005


def test_not_requested_changes_nothing():
    with realtime_priority(enabled=False) as grant:
        assert not grant.granted and grant.reason == "not requested"


def test_a_refusal_is_a_grant_not_an_exception(monkeypatch, caplog):
    def refuse(*_: object) -> None:
        raise PermissionError(1, "Operation not permitted")

    monkeypatch.setattr(os, "sched_setscheduler", refuse, raising=False)
    grant = request_realtime()
    assert not grant.granted and "CAP_SYS_NICE" in grant.reason


def test_sleep_until_never_returns_before_the_deadline():
    for delay in (0.0, SPIN_S / 2, 0.003, 0.012):
        deadline = time.perf_counter() + delay
        sleep_until(deadline)
        assert time.perf_counter() >= deadline


def test_sleep_until_ends_early_when_stopped():
    stop = threading.Event()
    threading.Timer(0.05, stop.set).start()
    t0 = time.perf_counter()
    sleep_until(t0 + 30.0, stop)
    assert time.perf_counter() - t0 < 10.0


def test_the_environment_turns_it_off(monkeypatch):
    monkeypatch.setenv("RLGP_EXEC_REALTIME", "0")
    grant = request_realtime()
    assert not grant.granted and grant.reason == "RLGP_EXEC_REALTIME=0"
    if hasattr(os, "sched_getscheduler"):
        assert os.sched_getscheduler(0) == os.SCHED_OTHER


@linux
def test_the_simulated_robots_loop_keeps_normal_priority_unless_asked():
    """Beside the executive, a SCHED_FIFO robot loop starves the server's own message threads: setpoints
    queued 0.2-0.4 s behind it and the executive stopped on tracking errors."""
    from rlgp_exec.sim.realtime import RealTimeLoop  # local: the sim package is not the HAL's

    seen: list[int] = []

    def tick() -> None:
        seen.append(os.sched_getscheduler(0))

    for realtime, ok in ((False, {os.SCHED_OTHER}), (True, {os.SCHED_OTHER, os.SCHED_FIFO})):
        seen.clear()
        loop = RealTimeLoop(0.005, tick, "test", realtime=realtime)
        loop.start()
        time.sleep(0.05)
        loop.stop()
        assert seen and set(seen) <= ok
    assert RealTimeLoop(0.01, tick).realtime is False
