"""``rlgp-exec bench executive``: the executive against a ``sim-robot`` process over Zenoh.

- ``loop_period_err_ms_p99``: |actual - nominal| control period [ms] at 100 Hz during execution of the
  sorting_hsr task (sense, plan, time, act, verify), p99; ``time_to_first_motion_s``: goal received ->
  first setpoint sent, for the same task.
- ``fault_reaction_ms_p99`` over ``n_faults`` faults injected while the arm moves: alternately the
  robot process freezing (SIGSTOP: its state goes stale) and an e-stop request from another thread.
  Reaction time: injection -> the executive holds (e-stop latched, or the stale state detected and
  nothing more commanded), p99.
"""

from __future__ import annotations

import logging
import os
import platform
import signal
import threading
import time
from pathlib import Path

import numpy as np

from rlgp_exec.executive.act import Actor, ActStatus, Signals
from rlgp_exec.executive.runner import RunOptions, connect, run_task
from rlgp_exec.expected_log import expected_warnings
from rlgp_exec.planning.validate import Phase
from rlgp_exec.scene import load_scene
from rlgp_exec.sim.robot_process import RobotProcess
from rlgp_exec.timing import TRACKING_HEADROOM, time_parameterize

__all__ = ["run_executive_bench"]

log = logging.getLogger(__name__)


def _p(xs: list[float], q: float) -> float | None:
    return float(np.percentile(xs, q)) if xs else None


def _fault_reactions(scene_path: Path, n_faults: int) -> tuple[list[float], list[str], list[str]]:
    scene = load_scene(scene_path)
    robot = RobotProcess(scene_path)
    proc, ep = robot.proc, robot.endpoint
    reactions: list[float] = []
    kinds: list[str] = []
    failures: list[str] = []
    hal, objects = connect(scene, RunOptions(backend="zenoh", endpoint=ep, objects="mocap"))
    try:
        objects.close()
        model = hal.model
        signals = Signals()
        actor = Actor(hal, signals)
        wrist = model.index("wrist_roll_joint")
        for k in range(n_faults):
            st = hal.read_state()
            assert st is not None
            q0 = st.model_q(model.joint_names)
            q1 = q0.copy()
            q1[wrist] = q0[wrist] + (1.5 if q0[wrist] < 0 else -1.5)
            res = time_parameterize(np.array([q0, q1]), model.limits.scaled(*TRACKING_HEADROOM))
            assert res.trajectory is not None
            if hal.lifecycle.name == "INACTIVE":
                hal.activate()
            actor.start(st)
            stall = k % 2 == 0
            injected: list[float] = []

            def inject(stall: bool = stall, injected: list[float] = injected) -> None:
                injected.append(time.perf_counter())
                if stall:
                    os.kill(proc.pid, signal.SIGSTOP)
                else:
                    signals.estop.set()

            timer = threading.Timer(0.4, inject)
            timer.start()
            out = actor.run_phases([Phase(np.array([q0, q1]), None)], [res.trajectory], None)
            t_react = time.perf_counter()
            timer.join()
            if stall:
                os.kill(proc.pid, signal.SIGCONT)
            expected = "stale_state" if stall else None
            got = out.violation.monitor if out.violation else out.status.value
            what = "stall" if stall else "estop"
            if (stall and out.violation is not None and out.violation.monitor == expected) or (
                not stall and out.status is ActStatus.ESTOPPED
            ):
                reactions.append((t_react - injected[0]) * 1e3)
                kinds.append(what)
                log.info("fault %d/%d (%s): held after %.1f ms", k + 1, n_faults, what, reactions[-1])
            else:
                failures.append(f"fault {k} ({what}): {got}")
                log.info("fault %d/%d (%s): NOT handled: %s", k + 1, n_faults, what, got)
            # recover: re-arm, wait for fresh state
            signals.estop.clear()
            if hal.lifecycle.name == "ESTOPPED":
                hal.rearm()
            end = time.monotonic() + 5.0
            while not hal.heartbeat_ok() and time.monotonic() < end:
                time.sleep(0.02)
            time.sleep(0.2)
    finally:
        hal.shutdown()
        robot.stop()
    return reactions, kinds, failures


#: the loggers that warn about the faults the bench injects (an e-stop latched, a stale state, a phase
#: stopped): expected here, so logged at INFO
FAULT_LOGGERS = (
    "rlgp_exec.executive.act", "rlgp_exec.hal.interface", "rlgp_exec.hal.zenoh_backend", "rlgp_exec.hal.validate",
    "rlgp_exec.executive.executive", "rlgp_exec.executive.monitors", "rlgp_exec.executive.states",
)


def run_executive_bench(task_scene: Path, fault_scene: Path, n_faults: int = 50, seed: int = 0) -> dict:
    log.info("task: %s on a sim-robot process over Zenoh (sense, plan, time, act, verify)", task_scene.name)
    with RobotProcess(task_scene) as robot:
        opts = RunOptions(backend="zenoh", endpoint=robot.endpoint, seed=seed, objects="mocap")
        result, ex = run_task(load_scene(task_scene), opts)
    errs = ex.actor.clock.period_err_ms
    log.info("task: %s in %.1f s planning, %.1f s execution; now %d faults while the arm moves",
             result.status.value, result.planning_time_s, result.execution_time_s, n_faults)
    with expected_warnings(FAULT_LOGGERS):
        reactions, kinds, failures = _fault_reactions(fault_scene, n_faults)
    by_kind = {k: [r for r, kk in zip(reactions, kinds, strict=True) if kk == k] for k in ("estop", "stall")}
    return {
        "task": "executive",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "run": result.as_dict(),
        "fault_failures": failures,
        "summary": {
            "task_status": result.status.value,
            "loop_period_err_ms_p50": _p(errs, 50),
            "loop_period_err_ms_p99": _p(errs, 99),
            "loop_cycles": len(errs),
            "time_to_first_motion_s": result.time_to_first_motion_s,
            "planning_time_s": result.planning_time_s,
            "execution_time_s": result.execution_time_s,
            "fault_reaction_ms_p50": _p(reactions, 50),
            "fault_reaction_ms_p99": _p(reactions, 99),
            "estop_reaction_ms_p99": _p(by_kind["estop"], 99),
            "stale_state_reaction_ms_p99": _p(by_kind["stall"], 99),
            "faults_injected": n_faults,
            "faults_handled": len(reactions),
        },
    }
