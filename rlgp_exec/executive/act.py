"""ACT: follow a timed plan through the HAL at the control rate, one phase at a time, with monitors.

Every cycle: read the state (stale -> FAULT), step the Ruckig streamer, send the arm/head setpoint and
the base twist (feed-forward plus a proportional correction of the odometry error, in the base frame),
record both, and run the monitors. An e-stop request latches the HAL's e-stop in the same cycle, so no
further setpoint goes out; a cancel or a STOP violation brings the robot to rest with a jerk-limited
stop first. Gripper phases close with a force limit and check that something was grasped.
"""

from __future__ import annotations

import enum
import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from rlgp_exec.executive.monitors import (
    Reaction,
    Tolerances,
    Violation,
    check_duration,
    check_start_state,
    check_tracking,
)
from rlgp_exec.executive.recorder import RecordSink
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.realtime import RealtimeGrant, realtime_priority, sleep_until
from rlgp_exec.hal.types import GripperCommand, Lifecycle, RobotState
from rlgp_exec.planning.validate import Phase
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.timing import Streamer, Trajectory

__all__ = ["ActOutcome", "ActStatus", "Actor", "ControlClock", "GripperAction", "Signals", "gripper_action"]

log = logging.getLogger(__name__)

BASE_GAIN = 2.0  # [1/s] odometry error correction
GRIPPER_S = 1.5  # [s] for the gripper to close or open
GRASP_FORCE_N = 10.0
EMPTY_GRASP_MARGIN = 0.05  # [rad] fingers this close to fully closed: nothing in the hand
OPENED_FRACTION = 0.5  # of the closed-to-open travel: fingers short of it after an open did not let go
STOP_TIMEOUT_S = 3.0
LIMIT_SNAP = 1e-3  # [rad | m] setpoints this far outside a position limit are clipped onto it
WORLD_CHECK_CYCLES = 10  # cycles between world checks (a moved object) during a phase


class ActStatus(enum.Enum):
    DONE = "done"
    VIOLATION = "violation"  # see the violation's reaction
    ESTOPPED = "estopped"
    CANCELLED = "cancelled"


@dataclass(frozen=True)
class ActOutcome:
    status: ActStatus
    phases_done: int
    violation: Violation | None = None
    held: str | None = None  # what the hand holds now (as far as the executive knows)


@dataclass
class Signals:
    """Requests from other threads (the daemon, a signal handler), seen by the control loop each cycle."""

    estop: threading.Event = field(default_factory=threading.Event)
    cancel: threading.Event = field(default_factory=threading.Event)


class ControlClock:
    """The control period: lock-step physics for the in-process sim backend, wall-clock deadlines
    otherwise. Records |period error| [ms] per cycle on the wall clock."""

    def __init__(self, hal: RobotInterface, period: float) -> None:
        self.period = period
        self._step = getattr(hal, "step", None) if hal.backend == "sim" else None
        self._next = time.perf_counter()
        self._last: float | None = None
        self.period_err_ms: list[float] = []

    def keepalive(self) -> None:
        """Lock-step sim only: advance one period so the (idle) simulated robot counts as alive after the
        executive has been busy elsewhere (planning). Real robots run on their own: nothing to do."""
        if self._step is not None:
            self._step(self.period)

    @property
    def wall_clock(self) -> bool:
        """Whether periods are kept on the wall clock (a robot of its own), not in lock-step with a sim."""
        return self._step is None

    def restart(self) -> None:
        self._next, self._last = time.perf_counter(), None

    def tick(self) -> None:
        if self._step is not None:
            self._step(self.period)
        else:
            self._next += self.period
            if self._next - time.perf_counter() < -5 * self.period:  # hopelessly late (a GC pause): re-anchor
                self._next = time.perf_counter()
            sleep_until(self._next)
        now = time.perf_counter()
        if self._last is not None:
            self.period_err_ms.append(abs(now - self._last - self.period) * 1e3)
        self._last = now


class Actor:
    """Runs phases on one HAL; owns the streamer so that consecutive phases are continuous."""

    def __init__(
        self,
        hal: RobotInterface,
        signals: Signals,
        recorder: RecordSink | None = None,
        period: float = 0.01,
        tolerances: Tolerances | None = None,
        on_first_motion: Callable[[], None] | None = None,
        realtime: bool = True,
    ) -> None:
        self.hal, self.model = hal, hal.model
        #: the control loop's thread under SCHED_FIFO while phases run, when the OS allows it
        self.realtime = realtime
        self.grant = RealtimeGrant(False, "SCHED_OTHER", "no phases run yet")
        self.signals, self.recorder = signals, recorder
        self.tol = tolerances or Tolerances()
        self.clock = ControlClock(hal, period)
        self.period = period
        self.names = list(hal.setpoint_names)
        self.idx = np.array([self.model.index(n) for n in self.names])
        self._lo = np.where(self.model.limits.continuous[self.idx], -np.inf, self.model.limits.lower[self.idx])
        self._hi = np.where(self.model.limits.continuous[self.idx], np.inf, self.model.limits.upper[self.idx])
        manip = self.model.manipulator()
        self.monitored = np.array(sorted({*self.model.group("base"), *self.model.group(manip.group)}))
        self.closed, self.open = manip.closed, manip.open
        self.streamer: Streamer | None = None
        self.cycles = 0
        self.base_distance_m = 0.0
        self._last_xy: tuple[float, float] | None = None
        self._on_first_motion = on_first_motion
        self.on_phase: Callable[[int, int], None] | None = None  # progress: (phase index, phases)
        #: inside the control loop: an e-stop request is latched by the loop itself within one cycle
        self.looping = False

    # ------------------------------------------------------------------ state
    def measured_q(self, st: RobotState) -> FloatArray:
        return st.model_q(self.model.joint_names)

    def _state(self) -> RobotState | Violation:
        if not self.hal.heartbeat_ok():
            return Violation(
                "stale_state", Reaction.FAULT, f"no fresh robot state within {self.hal.heartbeat_timeout} s"
            )
        st = self.hal.read_state()
        if st is None:
            return Violation("stale_state", Reaction.FAULT, "no robot state received yet")
        if st.estopped:
            return Violation("robot_estop", Reaction.FAULT, "the robot reports its e-stop engaged")
        if st.faults:
            return Violation("robot_fault", Reaction.FAULT, "; ".join(st.faults))
        return st

    # ------------------------------------------------------------------ one cycle
    def _send(self, st: RobotState, q: FloatArray, dq: FloatArray) -> None:
        x, y, yaw = st.base
        ex, ey, eyaw = q[0] - x, q[1] - y, math.remainder(q[2] - yaw, 2 * math.pi)
        vx, vy = dq[0] + BASE_GAIN * ex, dq[1] + BASE_GAIN * ey
        c, s = math.cos(yaw), math.sin(yaw)
        twist = (c * vx + s * vy, -s * vx + c * vy, dq[2] + BASE_GAIN * eyaw)
        res_b = self.hal.write_base_velocity(*twist)
        # a start measured a hair outside a limit (physics, encoder noise) is held inside it
        q_set = q[self.idx]
        q_in = np.clip(q_set, self._lo, self._hi)
        q_cmd = np.where(np.abs(q_in - q_set) <= LIMIT_SNAP, q_in, q_set)  # beyond that, the HAL refuses it
        res_q = self.hal.write_setpoint(q_cmd, dq[self.idx])
        if self._on_first_motion is not None and res_q and np.any(np.abs(dq) > 1e-6):
            self._on_first_motion()
            self._on_first_motion = None
        if self.recorder is not None:
            self.recorder.write(
                "/command",
                {
                    "names": self.names,
                    "q": q_cmd,
                    "dq": dq[self.idx],
                    "base_twist": twist,
                    "q_model": q,
                    "accepted": bool(res_q) and bool(res_b),
                    "refused": "" if res_q else res_q.reason,
                },
            )

    def _record_state(self, st: RobotState) -> None:
        if self._last_xy is not None:
            self.base_distance_m += math.hypot(st.base[0] - self._last_xy[0], st.base[1] - self._last_xy[1])
        self._last_xy = (st.base[0], st.base[1])
        if self.recorder is not None:
            self.recorder.write(
                "/robot_state",
                {
                    "stamp": st.stamp,
                    "names": st.names,
                    "q": st.q,
                    "dq": st.dq,
                    "base": st.base,
                    "base_velocity": st.base_velocity,
                    "gripper": st.gripper,
                    "estopped": st.estopped,
                    "faults": st.faults,
                },
            )

    def _estop_now(self) -> ActOutcome:
        if self.hal.lifecycle in (Lifecycle.INACTIVE, Lifecycle.ACTIVE):
            self.hal.estop()
        return ActOutcome(ActStatus.ESTOPPED, 0)

    def cycle(self, commanded: FloatArray | None = None) -> tuple[RobotState | Violation, FloatArray | None, bool]:
        """One control cycle: (state or violation, the commanded q, streamer finished)."""
        self.clock.tick()
        self.cycles += 1
        st = self._state()
        if isinstance(st, Violation):
            return st, None, False
        self._record_state(st)
        assert self.streamer is not None
        sp = self.streamer.step()
        self._send(st, sp.q_wrapped, sp.dq)
        return st, sp.q, sp.finished

    # ------------------------------------------------------------------ phases
    def start(self, st: RobotState) -> None:
        q = self.measured_q(st)
        if self.streamer is None:
            self.streamer = Streamer(self.model.limits, self.period, q)
        else:
            self.streamer.reset(q)
        self.clock.restart()

    def stop_motion(self) -> Violation | None:
        """Jerk-limited stop to rest; None when at rest, else why it could not finish."""
        assert self.streamer is not None
        self.streamer.stop()
        for _ in range(int(STOP_TIMEOUT_S / self.period)):
            if self.signals.estop.is_set():
                self._estop_now()
                return Violation("estop", Reaction.FAULT, "e-stop during the stop")
            st, _, done = self.cycle()
            if isinstance(st, Violation):
                return st
            if done:
                self.streamer.hold()
                return None
        return Violation("stop", Reaction.FAULT, f"not at rest after {STOP_TIMEOUT_S} s")

    def _wait(self, seconds: float) -> ActOutcome | Violation | None:
        assert self.streamer is not None
        self.streamer.hold()
        for _ in range(int(seconds / self.period)):
            if self.signals.estop.is_set():
                return self._estop_now()
            st, _, _ = self.cycle()
            if isinstance(st, Violation):
                return st
        return None

    def run_phases(
        self,
        phases: list[Phase],
        trajectories: list[Trajectory | None],
        held: str | None,
        world_check: Callable[[int, Phase, RobotState], Violation | None] | None = None,
    ) -> ActOutcome:
        """Follow ``phases`` (timed as ``trajectories``); returns how far it got and why it stopped.
        ``world_check`` runs before each phase and every ``WORLD_CHECK_CYCLES`` during it."""
        self.looping = True
        try:
            with realtime_priority(self.realtime and self.clock.wall_clock) as self.grant:
                return self._run_phases(phases, trajectories, held, world_check)
        finally:
            self.looping = False

    def _run_phases(
        self,
        phases: list[Phase],
        trajectories: list[Trajectory | None],
        held: str | None,
        world_check: Callable[[int, Phase, RobotState], Violation | None] | None,
    ) -> ActOutcome:
        for k, (ph, traj) in enumerate(zip(phases, trajectories, strict=True)):
            if self.signals.estop.is_set():  # before a gripper command as much as before a motion
                self._estop_now()
                return ActOutcome(ActStatus.ESTOPPED, k, None, held)
            if self.on_phase is not None:
                self.on_phase(k, len(phases))
            ends = f", then grasp {ph.grasp}" if ph.grasp else f", then release {ph.release}" if ph.release else ""
            log.info("phase %d of %d: %s%s", k + 1, len(phases), "motion" if traj is not None else "gripper", ends)
            st = self._state()
            if isinstance(st, Violation):
                return ActOutcome(ActStatus.VIOLATION, k, st, held)
            if world_check is not None:
                v = world_check(k, ph, st)
                if v is not None:
                    return ActOutcome(ActStatus.VIOLATION, k, v, held)
            if traj is not None and len(ph.path) > 1:
                v = check_start_state(self.model, self.measured_q(st), ph.path[0], self.tol, self.monitored)
                if v is not None:
                    return ActOutcome(ActStatus.VIOLATION, k, v, held)
                out = self._follow(traj, k, held, ph, world_check)
                if out is not None:
                    return out
            action = gripper_action(phases, k)
            if action is not None:
                out2 = self._gripper(action, k, held)
                if isinstance(out2, ActOutcome):
                    return out2
                held = out2
        return ActOutcome(ActStatus.DONE, len(phases), None, held)

    def _follow(
        self,
        traj: Trajectory,
        k: int,
        held: str | None,
        ph: Phase,
        world_check: Callable[[int, Phase, RobotState], Violation | None] | None,
    ) -> ActOutcome | None:
        assert self.streamer is not None
        self.streamer.follow(traj)
        t0 = self.cycles * self.period
        while True:
            if self.signals.estop.is_set():
                out = self._estop_now()
                return ActOutcome(out.status, k, None, held)
            if self.signals.cancel.is_set():
                v = self.stop_motion()
                return ActOutcome(ActStatus.CANCELLED if v is None else ActStatus.VIOLATION, k, v, held)
            st, q_cmd, done = self.cycle()
            if isinstance(st, Violation):
                return ActOutcome(ActStatus.VIOLATION, k, st, held)
            if done:
                return None
            assert q_cmd is not None
            v = check_tracking(self.model, self.measured_q(st), q_cmd, self.tol, self.monitored)
            v = v or check_duration(self.cycles * self.period - t0, traj.duration + 3 * self.streamer.lookahead)
            if v is None and world_check is not None and self.cycles % WORLD_CHECK_CYCLES == 0:
                v = world_check(k, ph, st)
            if v is not None:
                log.warning("phase %d: %s", k, v)
                v2 = self.stop_motion()
                return ActOutcome(ActStatus.VIOLATION, k, v2 or v, held)

    def _gripper(self, action: GripperAction, k: int, held: str | None) -> ActOutcome | str | None:
        """Close on an object or a knob, or open; what the hand holds afterwards (an object's name)."""
        grasp = action.grasp
        res = self.hal.gripper(GripperCommand.grasp(GRASP_FORCE_N) if grasp else GripperCommand.open())
        if not res:
            return ActOutcome(ActStatus.VIOLATION, k, Violation("gripper", Reaction.FAULT, res.reason), held)
        w = self._wait(GRIPPER_S)
        if isinstance(w, ActOutcome):
            return ActOutcome(w.status, k, None, held)
        if isinstance(w, Violation):
            return ActOutcome(ActStatus.VIOLATION, k, w, held)
        st = self._state()
        if isinstance(st, Violation):
            return ActOutcome(ActStatus.VIOLATION, k, st, held)
        if not grasp:
            if st.gripper < self.closed + OPENED_FRACTION * (self.open - self.closed):
                what = f"the knob of {action.target!r}" if action.knob else repr(action.target)
                return ActOutcome(ActStatus.VIOLATION, k, Violation(
                    "gripper", Reaction.FAULT,
                    f"the gripper did not open to let go of {what}: fingers at {st.gripper:.3f} after "
                    f"{GRIPPER_S} s (open is {self.open:.3f}, closed {self.closed:.3f})"), held)
            return None if not action.knob else held
        if st.gripper <= self.closed + EMPTY_GRASP_MARGIN:
            self.hal.gripper(GripperCommand.open())
            self._wait(GRIPPER_S)
            what = f"the knob of {action.target!r}" if action.knob else repr(action.target)
            return ActOutcome(
                ActStatus.VIOLATION,
                k,
                Violation("grasp", Reaction.REPLAN, f"closed on nothing when grasping {what}"),
                None,
            )
        return held if action.knob else action.target


class GripperAction(NamedTuple):
    grasp: bool  # close with a force limit (else open)
    target: str  # the object, or the cabinet whose knob
    knob: bool


def gripper_action(phases: list[Phase], k: int) -> GripperAction | None:
    """What the gripper does when phase ``k`` ends: grasp/release an object (``grasp``/``release``),
    take a knob (the phase reaches a knob and the next one drives the drawer), let go of it (the phase
    drove the drawer), or nothing."""
    ph = phases[k]
    if ph.grasp is not None:
        return GripperAction(True, ph.grasp, False)
    if ph.release is not None:
        return GripperAction(False, ph.release, False)
    if ph.knob is not None and ph.drives_drawer:
        return GripperAction(False, ph.knob, True)
    if ph.knob is not None and k + 1 < len(phases) and phases[k + 1].drives_drawer:
        return GripperAction(True, ph.knob, True)
    return None
