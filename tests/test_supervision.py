"""Supervision of the executive: every state-machine transition defined, e-stop and cancel arriving in every
state and stage, any exception bringing the robot to rest in FAULT with its reason, latched states left
only by an operator's request, and the daemon's worker waiting for the robot and for rearm/reset instead
of consuming goals, and never dying silently."""

from __future__ import annotations

import itertools
import json
import os
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.executive import ExecState, Executive, Recorder, SimMocap, StateMachine, TaskStatus, read_recording
from rlgp_exec.executive.states import LATCHED, IllegalTransitionError, allowed
from rlgp_exec.hal import Lifecycle, make_backend
from rlgp_exec.planning.plan import Plan
from rlgp_exec.scene import load_scene

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "shelf_hsr.toml"
S = ExecState


# ---------------------------------------------------------------------------------- the table
def _machine_in(state: ExecState) -> StateMachine:
    """A machine driven into ``state`` through allowed transitions only."""
    sm = StateMachine()
    path = {
        S.IDLE: [],
        S.SENSING: [S.SENSING],
        S.PLANNING: [S.SENSING, S.PLANNING],
        S.EXECUTING: [S.SENSING, S.PLANNING, S.EXECUTING],
        S.RECOVERING: [S.SENSING, S.PLANNING, S.EXECUTING, S.RECOVERING],
        S.ESTOPPED: [S.ESTOPPED],
        S.FAULT: [S.FAULT],
    }[state]
    for s in path:
        sm.to(s, "test")
    assert sm.state is state
    return sm


@pytest.mark.parametrize("source, target", list(itertools.product(ExecState, ExecState)))
def test_every_transition_is_defined_and_latches_are_left_only_by_an_operator(source, target):
    sm = _machine_in(source)
    n = len(sm.history)
    if allowed(source, target):
        sm.to(target, "test")
        assert sm.state is target and len(sm.history) == n + (target is not source)
    else:
        with pytest.raises(IllegalTransitionError) as e:
            sm.to(target, "test")
        assert e.value.preempted == (source in LATCHED) and sm.state is source and len(sm.history) == n
        assert source.name in str(e.value) and target.name in str(e.value)
    # e-stop and fault are reachable from every state; a latch is left to IDLE only by release()
    assert allowed(source, S.ESTOPPED) and allowed(source, S.FAULT)
    if source in LATCHED and target is S.IDLE:
        assert not allowed(source, target) and allowed(source, target, operator=True)
    # settle never overwrites a latch, and otherwise goes where it was asked if allowed
    sm2 = _machine_in(source)
    if source in LATCHED:
        assert sm2.settle(S.IDLE) is source
    elif allowed(source, S.IDLE):
        assert sm2.settle(S.IDLE) is S.IDLE


def test_history_is_bounded():
    sm = StateMachine()
    for _ in range(6000):
        sm.to(S.SENSING)
        sm.to(S.IDLE)
    assert len(sm.history) == 10_000 and sm.reason == ""


# ---------------------------------------------------------------------------------- the executive
@pytest.fixture
def sim(tmp_path):
    scene = load_scene(SCENE)
    hal = make_backend("sim", scene=scene)
    hal.configure()
    rec = Recorder(tmp_path / "run.mcap")
    ex = Executive(hal, scene, SimMocap(hal), recorder=rec, robot_wait_s=1.0)
    yield ex, hal, rec
    rec.close()
    hal.shutdown()


def _on_entering(ex: Executive, state: ExecState, fn) -> None:
    """Call ``fn`` once, the first time the executive enters ``state``."""
    done: list[bool] = []

    def listener(tr):
        if tr.target is state and not done:
            done.append(True)
            fn()

    ex.sm.listeners.append(listener)


def _from_another_thread(fn):
    def call():
        t = threading.Thread(target=fn)
        t.start()
        t.join()

    return call


@pytest.mark.parametrize("stage", [S.SENSING, S.PLANNING, S.EXECUTING])
def test_an_estop_in_any_stage_ends_the_task_estopped_and_rearm_then_a_task_succeeds(sim, stage):
    ex, hal, _ = sim
    _on_entering(ex, stage, _from_another_thread(ex.estop))
    q0 = hal.sim.measured_q()
    result = ex.run()
    assert result.status is TaskStatus.ESTOPPED, result.detail
    assert ex.sm.state is S.ESTOPPED and hal.lifecycle is Lifecycle.ESTOPPED
    assert np.abs(hal.sim.measured_q() - q0).max() < 5e-3  # it never moved
    assert ex.run().status is TaskStatus.ESTOPPED  # refused until re-armed
    ex.rearm()
    assert ex.sm.state is S.IDLE
    ex.sm.listeners.clear()
    again = ex.run()
    assert again.status is TaskStatus.SUCCEEDED, again.detail


@pytest.mark.parametrize("stage", [S.SENSING, S.PLANNING])
def test_a_cancel_before_motion_ends_the_task_cancelled_without_moving(sim, stage):
    ex, hal, _ = sim
    _on_entering(ex, stage, ex.cancel)
    q0 = hal.sim.measured_q()
    result = ex.run()
    assert result.status is TaskStatus.CANCELLED and result.detail == "cancelled before motion", result.detail
    assert ex.sm.state is S.IDLE and np.abs(hal.sim.measured_q() - q0).max() < 5e-3


@pytest.mark.parametrize("state", list(ExecState))
def test_estop_and_cancel_requests_in_every_state_are_defined(sim, state):
    """Forced into each state with no task running (as between a daemon's tasks): an e-stop latches the
    executive and the HAL at once; a cancel changes nothing; a task is refused or runs, never raises."""
    ex, hal, _ = sim
    ex.sm._state = state
    ex.cancel()
    assert ex.sm.state is state
    ex.estop()
    assert ex.sm.state is S.ESTOPPED and hal.lifecycle is Lifecycle.ESTOPPED
    assert ex.run().status is TaskStatus.ESTOPPED
    with pytest.raises(Exception, match="not FAULT"):
        ex.reset()
    ex.rearm()
    assert ex.sm.state is S.IDLE and not ex.signals.estop.is_set()


def test_an_estop_during_a_plan_that_then_fails_stays_estopped_and_rearm_is_accepted(sim, monkeypatch):
    ex, hal, _ = sim

    def failing_planner(scene, planner, **kw):
        threading.Thread(target=ex.estop).start()
        time.sleep(0.2)
        return Plan(False, planner, (), np.zeros((0, 11)), (), 0.2, 0, 0, None, "no valid plan after 0 candidates")

    monkeypatch.setattr("rlgp_exec.planning.registry.plan", failing_planner)
    result = ex.run()
    assert result.status is TaskStatus.ESTOPPED and "no valid plan" in result.detail, result.detail
    assert ex.sm.state is S.ESTOPPED and hal.lifecycle is Lifecycle.ESTOPPED
    ex.rearm()
    assert ex.sm.state is S.IDLE and hal.lifecycle is Lifecycle.INACTIVE


@pytest.mark.parametrize("where", ["planner", "control loop", "timing"])
def test_an_exception_anywhere_in_a_task_brings_the_robot_to_rest_in_fault_with_its_reason(sim, monkeypatch, where):
    ex, hal, rec = sim
    if where == "planner":
        monkeypatch.setattr("rlgp_exec.planning.registry.plan", lambda *a, **k: 1 / 0)
    elif where == "timing":
        monkeypatch.setattr(ex, "_time", lambda plan: [][1])
    else:
        cycle = ex.actor.cycle

        def breaking_cycle(*a):  # 0.8 s into the first motion
            if ex.actor.cycles > 80:
                raise OSError(28, "No space left on device")
            return cycle(*a)

        monkeypatch.setattr(ex.actor, "cycle", breaking_cycle)
    result = ex.run()
    assert result.status is TaskStatus.FAULT and result.detail.startswith("internal error: "), result.detail
    assert ex.sm.state is S.FAULT and ex.sm.reason == result.detail
    assert hal.lifecycle is not Lifecycle.ACTIVE  # deactivated: holding, base stopped
    q = hal.sim.measured_q()
    for _ in range(50):
        hal.step(0.01)
    assert np.abs(hal.sim.measured_q() - q).max() < 2e-3  # at rest
    assert ex.run().status is TaskStatus.FAULT  # refused until reset
    ex.reset()
    rec.close()
    R = read_recording(rec.path)
    assert [e["detail"] for _, e in R.topic("/events") if e["kind"] == "fault"] == [result.detail]
    assert [d["to"] for _, d in R.topic("/transitions")][-2:] == ["fault", "idle"]


def test_a_task_without_fresh_robot_state_waits_then_fails_without_moving(sim, monkeypatch):
    ex, hal, _ = sim
    monkeypatch.setattr(hal, "heartbeat_ok", lambda: False)
    t0 = time.monotonic()
    result = ex.run()
    assert result.status is TaskStatus.FAILED and "waited 1 s for the robot" in result.detail, result.detail
    assert time.monotonic() - t0 >= 1.0 and ex.sm.state is S.IDLE and result.plans == 0


# ---------------------------------------------------------------------------------- the daemon's worker
@pytest.fixture
def daemon(tmp_path):
    from rlgp_exec.executive.daemon import Daemon, DaemonOptions
    from rlgp_exec.executive.runner import RunOptions
    from rlgp_exec.sim.robot_process import free_endpoint

    d = Daemon(load_scene(SCENE), RunOptions(backend="sim"), DaemonOptions(free_endpoint(), "", tmp_path))
    d.start()
    yield d
    d.stop()


def _goal(d, literals=("(on block tray)",)) -> dict:
    return d._on_goal(json.dumps({"literals": list(literals)}).encode())


def _until(cond, timeout: float = 60.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def test_queued_goals_wait_for_fresh_robot_state_instead_of_failing(daemon, monkeypatch):
    hal = daemon.executive.hal
    lost = threading.Event()
    lost.set()
    beat = hal.heartbeat_ok
    monkeypatch.setattr(hal, "heartbeat_ok", lambda: not lost.is_set() and beat())
    assert _goal(daemon)["ok"]
    assert _until(lambda: daemon.status()["waiting"] == "robot", 5.0)
    time.sleep(1.5)  # longer than any heartbeat timeout: the goal is still waiting, not failed
    assert daemon.last is None and daemon.status()["waiting"] == "robot"
    lost.clear()  # the robot is back
    assert _until(lambda: daemon.last is not None)
    assert daemon.last["status"] == "succeeded", daemon.last


def test_goals_queued_before_an_estop_are_dropped_and_nothing_runs_on_rearm(daemon):
    ex = daemon.executive
    _on_entering(ex, S.EXECUTING, _from_another_thread(ex.estop))
    assert _goal(daemon)["ok"] and _goal(daemon, ["(on block table)"])["ok"]
    assert _until(lambda: daemon.last is not None)
    assert daemon.last["status"] == "estopped" and daemon.status()["state"] == "estopped"
    assert daemon.status()["dropped"] == 1 and daemon.queue.qsize() == 0
    refused = _goal(daemon)
    assert refused["ok"] is False and "rearm" in refused["error"]
    ex.sm.listeners.pop()
    ex.rearm()
    time.sleep(0.5)
    assert daemon.served == 1 and daemon.status()["state"] == "idle"


def test_a_worker_that_dies_latches_fault_refuses_goals_and_says_why(daemon, monkeypatch):
    def broken(task):
        raise RuntimeError("executive bug")

    monkeypatch.setattr(daemon, "_run", broken)
    assert _goal(daemon)["ok"]
    assert daemon.dead.wait(10.0)
    st = daemon.status()
    assert st["state"] == "fault" and "RuntimeError: executive bug" in st["fatal"], st
    r = _goal(daemon)
    assert r["ok"] is False and "restart the daemon" in r["error"]


def test_a_recording_that_cannot_be_written_stops_and_the_task_goes_on(sim):
    """The disk fills mid-motion: the recording stops (what reached the file still reads), the result and
    ``recording_error`` say so, and the task carries on to its goal as if nothing were recorded."""
    ex, _, rec = sim
    cycle = ex.actor.cycle
    full = os.open("/dev/full", os.O_WRONLY)

    def filling_cycle(*a):
        if ex.actor.cycles == 60 and rec.error is None:
            os.dup2(full, rec._fd)  # the recorder's descriptor now answers ENOSPC
        return cycle(*a)

    ex.actor.cycle = filling_cycle  # type: ignore[method-assign]
    try:
        result = ex.run()
    finally:
        os.close(full)
    assert result.status is TaskStatus.SUCCEEDED and result.verified, result.detail
    assert result.recording_error is not None and "No space left" in result.recording_error
    assert ex.recording_error == result.recording_error == rec.error
    R = read_recording(rec.path)
    assert not R.complete and len(R.topic("/robot_state")) > 10
