"""Ruckig online motion generation at the control rate: follow, re-target, stop, hold.

Each cycle the streamer asks Ruckig for a jerk-limited motion from its current state (q, dq, ddq)
towards a target state, and outputs that motion's state one control period later:

- FOLLOW, on the reference (every joint within ``CATCH_UP`` of where the trajectory is now, the
  look-ahead point ``L`` ahead still inside it): Ruckig's *velocity* interface, asked to reach the
  reference's acceleration and a velocity ``v*`` in exactly ``L``; ``v*`` is chosen so that the
  position after ``L`` lands on the reference's (the integral of a cubic velocity ramp:
  ``q + L (v + v*) / 2 + L^2 (a - a*) / 12 = q_ref(t + L)``). Ruckig then acts as a jerk-limited
  tracking filter in phase with the reference, at a fraction of the position interface's cost (one
  velocity-interface update: ~2 us for 8 DoF against ~10 us; the position interface's blocked intervals
  made a third of its cycles calculate twice). A velocity-interface result stretched past ``L`` is
  kept: it still moves towards the reference within the limits, and the next cycle plans again.
- FOLLOW, off the reference (a re-target to a trajectory that starts elsewhere) or landing (the
  look-ahead past the end): the position interface, the reference's state ``L`` ahead to be reached
  in exactly ``L`` (``minimum_duration`` with time synchronisation): Ruckig plans the catch-up with
  its own braking. When time synchronisation falls into a blocked interval (one joint cannot take
  exactly ``L``: Ruckig then stretches every joint, seen 13 s for 0.4 s asked), longer horizons are
  tried, then each joint on its own.
  ``L`` defaults to two acceleration ramp times, 2 max(a / j): shorter cuts corners less. A
  trajectory timed at the full limits cannot be tracked exactly by a jerk-limited follower (TOPPRA's
  acceleration jumps); time the trajectories the streamer follows with ``TRACKING_HEADROOM`` (90 %
  velocity, 80 % acceleration) and the tracking error stays in the millimetres.
- STOP: zero velocity and acceleration through Ruckig's velocity interface: a jerk-limited ramp.
- HOLD: the position where it is, at rest.

Re-targeting switches the followed trajectory in place: Ruckig always starts from the current
state, so position, velocity and acceleration stay continuous. Continuous joints are handled
unwrapped; a new trajectory is shifted by whole turns to start next to the current angles.

The base's x and y limits act on world-frame axes here, at sqrt(2) times the base-frame limit:
the trajectories followed already respect the base-frame box (see ``toppra_param``), whose
world-frame components can reach sqrt(2) v on a diagonal.
"""

from __future__ import annotations

import enum
import logging
import time
from dataclasses import dataclass

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, RuckigError, Synchronization

from rlgp_exec.robot.config import BASE_JOINTS
from rlgp_exec.robot.limits import JointLimits
from rlgp_exec.timing.trajectory import FloatArray, TimingError, Trajectory

log = logging.getLogger(__name__)

__all__ = ["TRACKING_HEADROOM", "Setpoint", "StreamMode", "Streamer", "stop_time_bound"]

#: (velocity, acceleration) factors for timing trajectories the streamer follows: ``limits.scaled(*TRACKING_HEADROOM)``
TRACKING_HEADROOM = (0.9, 0.8)
LOOKAHEAD_RAMPS = 2.0  # default look-ahead: this many acceleration ramp times max(a / j)
BLOCKED_STRETCH = 1.25  # a synchronised duration this many times the requested one: a blocked interval
RESYNC_FACTORS = (1.5, 2.0, 3.0)  # longer look-ahead horizons tried then
CATCH_UP = 0.02  # [m or rad] a joint farther than this from the reference: the position interface catches up


class StreamMode(enum.Enum):
    HOLD = "hold"
    FOLLOW = "follow"
    STOP = "stop"


@dataclass(frozen=True)
class Setpoint:
    """One control-cycle output; positions unwrapped (``q_wrapped`` for the wire)."""

    t: float  # [s] since the streamer started
    q: FloatArray
    dq: FloatArray
    ddq: FloatArray
    q_wrapped: FloatArray
    mode: StreamMode
    finished: bool  # FOLLOW: trajectory done and reached; STOP: at rest; HOLD: always True
    compute_us: float  # this cycle's Ruckig calls, wall clock from Python [us]
    ruckig_us: float  # Ruckig's own calculation time for the cycle, summed over its calls [us]
    ruckig_calls: int = 1  # Ruckig updates this cycle (more than one: a blocked interval was resynchronised)


def stop_time_bound(limits: JointLimits, dq: FloatArray, ddq: FloatArray) -> float:
    """An upper bound [s] on a jerk-limited stop from (dq, ddq): ramp the acceleration to the
    opposite limit, brake, ramp it back to zero, per joint (the slowest joint decides)."""
    a, j = limits.acceleration, limits.jerk
    t = (np.abs(ddq) + a) / j + np.abs(dq) / a + a / j + np.abs(ddq) / a
    return float(np.max(t))


class Streamer:
    """Jerk-limited setpoints at a fixed period ``dt`` [s] (0.01 s for the HSR's 100 Hz controllers)."""

    def __init__(
        self, limits: JointLimits, dt: float = 0.01, q0: FloatArray | None = None, lookahead: float | None = None
    ) -> None:
        if not (dt > 0 and np.isfinite(dt)):
            raise TimingError(f"control period must be > 0 s, got {dt}")
        for what in ("velocity", "acceleration", "jerk"):
            v = getattr(limits, what)
            if not np.all(np.isfinite(v) & (v > 0)):
                raise TimingError(f"{what} limits must be finite and > 0, got {v.tolist()}")
        self.limits, self.dt, n = limits, float(dt), limits.n
        self._otg = Ruckig(n, self.dt)
        self._inp, self._out = InputParameter(n), OutputParameter(n)
        vmax = limits.velocity.copy()
        if limits.names[:3] == BASE_JOINTS:
            vmax[:2] *= np.sqrt(2.0)
        self._vmax, self._amax = vmax, limits.acceleration.copy()
        self._inp.max_velocity = vmax.tolist()
        self._inp.max_acceleration = self._amax.tolist()
        self._inp.max_jerk = limits.jerk.tolist()
        ramp = float(np.max(limits.acceleration / limits.jerk))
        self.lookahead = max(LOOKAHEAD_RAMPS * ramp, 2.0 * self.dt) if lookahead is None else float(lookahead)
        if not (self.lookahead >= self.dt and np.isfinite(self.lookahead)):
            raise TimingError(f"look-ahead must be at least one control period ({self.dt} s), got {lookahead}")
        self.t = 0.0
        self.q = np.zeros(n) if q0 is None else np.asarray(q0, float).copy()
        self.dq, self.ddq = np.zeros(n), np.zeros(n)
        self.mode = StreamMode.HOLD
        self._hold_q = self.q.copy()
        self._traj: Trajectory | None = None
        self._offset = np.zeros(n)
        self._t_traj = 0.0
        self._calls, self._calc_us = 0, 0.0  # this cycle's Ruckig updates and their calculation time [us]

    # ------------------------------------------------------------------ commands
    def reset(self, q: FloatArray, dq: FloatArray | None = None, ddq: FloatArray | None = None) -> None:
        """Take the robot's measured state as the current state (and hold there)."""
        q = np.asarray(q, float)
        if q.shape != (self.limits.n,) or not np.all(np.isfinite(q)):
            raise TimingError(f"state must be {self.limits.n} finite values, got {q}")
        self.q = q.copy()
        self.dq = np.zeros_like(q) if dq is None else np.asarray(dq, float).copy()
        self.ddq = np.zeros_like(q) if ddq is None else np.asarray(ddq, float).copy()
        self.hold()

    def follow(self, trajectory: Trajectory) -> None:
        """Follow ``trajectory`` from now on (also the way to re-target mid-motion)."""
        if trajectory.names != self.limits.names:
            raise TimingError(
                f"trajectory joints {list(trajectory.names)} != streamer joints {list(self.limits.names)}"
            )
        start = trajectory.sample(0.0, wrap=False)[0]
        turns = np.round((self.q - start) / (2 * np.pi)) * (2 * np.pi)
        self._offset = np.where(self.limits.continuous, turns, 0.0)
        self._traj, self._t_traj = trajectory, 0.0
        self.mode = StreamMode.FOLLOW

    retarget = follow

    def stop(self) -> None:
        """Brake to rest with a jerk-limited ramp (pre-emption, e-stop ramp)."""
        self.mode = StreamMode.STOP
        self._traj = None

    def hold(self) -> None:
        self.mode = StreamMode.HOLD
        self._traj = None
        self._hold_q = self.q.copy()

    def _reachable_target(self, dq: FloatArray, ddq: FloatArray) -> tuple[FloatArray, FloatArray]:
        """Clip a target (velocity, acceleration) to one Ruckig accepts: inside the limits, and with
        |v| + a^2 / (2 j) <= v_max, the peak velocity on either side of the target state under the
        jerk limit (Ruckig checks both: the state before a braking target was faster)."""
        v = np.clip(dq, -0.9999 * self._vmax, 0.9999 * self._vmax)
        a = np.clip(ddq, -0.9999 * self._amax, 0.9999 * self._amax)
        room = np.sqrt(2.0 * self.limits.jerk * np.maximum(0.9999 * self._vmax - np.abs(v), 0.0))
        a = np.sign(a) * np.minimum(np.abs(a), 0.999 * room)
        return v, a

    def _track_target(self) -> bool:
        """On the reference: the velocity-interface target (see the module docstring); False when the
        streamer is off the reference or the look-ahead point is past the trajectory's end."""
        assert self._traj is not None
        L = self.lookahead
        if self._t_traj + L >= self._traj.duration:
            return False
        q_now = self._traj.sample(self._t_traj, wrap=False)[0] + self._offset
        if np.max(np.abs(q_now - self.q)) > CATCH_UP:
            return False
        q_r, _, a_r = self._traj.sample(self._t_traj + L, wrap=False)
        v_star = 2.0 * (q_r + self._offset - self.q - L * L * (self.ddq - a_r) / 12.0) / L - self.dq
        v_t, a_t = self._reachable_target(v_star, a_r)
        inp = self._inp
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization, inp.minimum_duration = Synchronization.Time, L
        inp.target_velocity, inp.target_acceleration = v_t.tolist(), a_t.tolist()
        return True

    def _follow_target(self, horizon: float, sync: Synchronization) -> None:
        """Target the followed trajectory's state ``horizon`` [s] ahead, to be reached in that time
        (position interface)."""
        assert self._traj is not None
        inp = self._inp
        inp.control_interface = ControlInterface.Position
        inp.synchronization = sync
        inp.minimum_duration = horizon if sync is Synchronization.Time else None
        q_t, dq_t, ddq_t = self._traj.sample(self._t_traj + horizon, wrap=False)
        v_t, a_t = self._reachable_target(dq_t, ddq_t)
        inp.target_position = (q_t + self._offset).tolist()
        inp.target_velocity, inp.target_acceleration = v_t.tolist(), a_t.tolist()

    def _blocked(self) -> bool:
        """Time synchronisation fell into a blocked interval: a joint cannot take exactly the requested
        duration (its feasible durations have a gap), so every joint was stretched far beyond it (seen:
        0.4 s requested, 13 s computed: the streamer braked hard and fell ~0.6 rad behind)."""
        wanted = self._inp.minimum_duration or self.lookahead
        return self._out.trajectory.duration > BLOCKED_STRETCH * wanted

    def _update(self) -> Result | None:
        """One Ruckig update; None when its synchronisation fails numerically (it raises then). Counts
        the call and Ruckig's own calculation time towards the cycle's."""
        self._calls += 1
        try:
            res = self._otg.update(self._inp, self._out)
        except RuckigError as e:
            log.debug("Ruckig: %s", str(e).splitlines()[0] if str(e) else type(e).__name__)
            return None
        self._calc_us += float(self._out.calculation_duration)
        return res

    def _resync(self) -> Result | None:
        """Longer horizons first (the reference further ahead, reached in that time), then each joint on
        its own towards the look-ahead target: the first that does not stretch is taken."""
        for factor in RESYNC_FACTORS:
            self._follow_target(self.lookahead * factor, Synchronization.Time)
            res = self._update()
            if res is not None and (res != Result.Working or not self._blocked()):
                return res
        self._follow_target(self.lookahead, Synchronization.No)
        return self._update()

    # ------------------------------------------------------------------ cycle
    def step(self) -> Setpoint:
        """Advance one control period and return the new setpoint."""
        inp = self._inp
        inp.current_position, inp.current_velocity, inp.current_acceleration = (
            self.q.tolist(),
            self.dq.tolist(),
            self.ddq.tolist(),
        )
        finished_traj = False
        if self.mode is StreamMode.STOP:
            inp.control_interface = ControlInterface.Velocity
            inp.synchronization, inp.minimum_duration = Synchronization.No, None
            inp.target_velocity = [0.0] * self.limits.n
            inp.target_acceleration = [0.0] * self.limits.n
        elif self.mode is StreamMode.FOLLOW and self._traj is not None:
            if not self._track_target():
                self._follow_target(self.lookahead, Synchronization.Time)
            self._t_traj += self.dt
            finished_traj = self._t_traj >= self._traj.duration
        else:
            inp.control_interface = ControlInterface.Position
            inp.synchronization, inp.minimum_duration = Synchronization.No, None
            inp.target_position = self._hold_q.tolist()
            inp.target_velocity = [0.0] * self.limits.n
            inp.target_acceleration = [0.0] * self.limits.n
        self._calls, self._calc_us = 0, 0.0
        t0 = time.perf_counter()
        res = self._update()
        # a velocity-interface cycle stretched by a blocked interval still moves towards the reference
        # within the limits (the next cycle plans again); a position-interface one falls far behind
        tracking = self._inp.control_interface is ControlInterface.Velocity
        blocked = not tracking and res == Result.Working and self._blocked()
        if self.mode is StreamMode.FOLLOW and (res is None or blocked):
            res = self._resync()
        compute_us = (time.perf_counter() - t0) * 1e6
        if res is None:
            raise TimingError(f"Ruckig failed on every synchronisation; state q={self.q}, dq={self.dq}")
        if res not in (Result.Working, Result.Finished):
            raise TimingError(f"Ruckig rejected the cycle input ({res}); state q={self.q}, dq={self.dq}")
        out = self._out
        self.q = np.asarray(out.new_position)
        self.dq = np.asarray(out.new_velocity)
        self.ddq = np.asarray(out.new_acceleration)
        self.t += self.dt
        if self.mode is StreamMode.FOLLOW:
            finished = finished_traj and res == Result.Finished
        elif self.mode is StreamMode.STOP:
            finished = bool(np.all(np.abs(self.dq) < 1e-9) and np.all(np.abs(self.ddq) < 1e-9))
        else:
            finished = True
        return Setpoint(
            self.t,
            self.q.copy(),
            self.dq.copy(),
            self.ddq.copy(),
            self.limits.wrap(self.q),
            self.mode,
            finished,
            compute_us,
            self._calc_us,
            self._calls,
        )
