"""Time-optimal path parameterisation with TOPPRA under velocity and acceleration limits.

A phase path (T, N) of straight segments is resampled finely (``densify``: the cubic then follows
the segments, the ones the planners checked) and interpolated by a shape-preserving cubic (PCHIP),
parameterised by normalised cumulative chord length, and retimed rest-to-rest by TOPPRA (seidel solver). The
omnidirectional base's velocity limits hold along the *base* frame's axes: the path's world-frame
velocity rotated by -yaw must satisfy |v_bx| <= vx, |v_by| <= vy. This is exact, as a
path-varying limit on the world-frame x/y joints: at each gridpoint the largest path speed is
sdot_max(s) = min_i v_i / |(R(-yaw) [x', y'])_i|, imposed as |x'| sdot <= |x'| sdot_max(s) (and
likewise for y). Base accelerations use the conservative world-frame bound a / sqrt(2).

TOPPRA enforces the limits at gridpoints; between them the spline can overshoot by a few per
cent (p''(s) sdot^2 is a product of two functions that vary within an interval, so re-solving with
scaled limits does not remove it). Every result is therefore sampled densely and, if it breaks a
limit, slowed down uniformly: dividing the path speed by c divides velocities by c and accelerations
by c^2 exactly, so c = max(v ratio, sqrt(a ratio)) restores the limits at the cost of a few per cent
of duration. The returned trajectory respects the limits at every check sample, or the status says
why not.
"""

from __future__ import annotations

import functools
import itertools
import logging
import math
import time
from collections.abc import Sequence

import numpy as np
import toppra as ta
import toppra.algorithm as ta_algo
import toppra.constraint as ta_con
from scipy.interpolate import PchipInterpolator

from rlgp_exec.robot.config import BASE_JOINTS
from rlgp_exec.robot.limits import JointLimits
from rlgp_exec.timing.trajectory import (
    FloatArray,
    PhaseKind,
    Segment,
    TimingError,
    TimingResult,
    TimingStatus,
    Trajectory,
    _Spline,
    as_path,
)

__all__ = [
    "DENSIFY_STEP",
    "MAX_RETRIES",
    "ConstAccelPiece",
    "PchipPath",
    "densify",
    "time_parameterize",
    "time_parameterize_phases",
]

log = logging.getLogger(__name__)
logging.getLogger("toppra").setLevel(logging.ERROR)  # its uncontrollable-grid warning is our fallback path

MAX_RETRIES = 3
CHECK_PER_INTERVAL = 32  # samples per gridpoint interval when verifying limits (an interval's peak lies between them)
POSITION_TOLERANCE = 1e-3  # [m or rad] the spline may pass a position limit by this much
_DUP = 1e-9
CUSP_DEG = 80.0  # [deg] a path turning more than this at a waypoint stops there when no smooth timing exists
DENSIFY_STEP = 0.02  # [m or rad] the straight segments are resampled this finely before interpolation


class PchipPath(ta.interpolator.AbstractGeometricPath):
    """Shape-preserving cubic (PCHIP) through the waypoints, per joint: C1, and it never leaves the
    range of two neighbouring waypoints, so a path whose waypoints respect the position limits does
    too (a natural cubic spline overshoots)."""

    def __init__(self, ss: FloatArray, waypoints: FloatArray) -> None:
        self._ss, self._wp = ss, waypoints
        self._f = PchipInterpolator(ss, waypoints, axis=0)
        self._d = (self._f, self._f.derivative(1), self._f.derivative(2))

    def __call__(self, path_positions, order: int = 0):
        return self._d[order](path_positions)

    @property
    def dof(self) -> int:
        return int(self._wp.shape[1])

    @property
    def path_interval(self) -> FloatArray:
        return np.array([self._ss[0], self._ss[-1]])

    @property
    def waypoints(self):
        return self._ss, self._wp


class _LeftLimit:
    """The path with its second derivative taken from the left (just before each s): PCHIP's p'' jumps
    at the waypoints, and TOPPRA's constraint at a waypoint gridpoint sees only the right-hand value."""

    def __init__(self, path: PchipPath) -> None:
        self.path, self.dof = path, path.dof

    def __call__(self, s, order: int = 0):
        if order == 2:
            return self.path(np.maximum(np.asarray(s, float) - 1e-9, 0.0), 2)
        return self.path(s, order)


class _LeftAcceleration(ta_con.JointAccelerationConstraint):
    """Joint acceleration limits on the left-hand limit of the path's second derivative (collocated)."""

    def compute_constraint_params(self, path, gridpoints, *args, **kwargs):
        return super().compute_constraint_params(_LeftLimit(path), gridpoints, *args, **kwargs)


class ConstAccelPiece:
    """The time parameterisation TOPPRA computed, with constant path acceleration between gridpoints.

    From gridpoints s_i and path speeds sd_i: sdd_i = (sd_{i+1}^2 - sd_i^2) / (2 ds_i) and
    dt_i = 2 ds_i / (sd_i + sd_{i+1}); then q = p(s), dq = p'(s) sd, ddq = p''(s) sd^2 + p'(s) sdd.
    Evaluated vectorised (toppra's own evaluator loops in Python).
    """

    def __init__(self, path: PchipPath, ss: FloatArray, sd: FloatArray) -> None:
        self.path = path
        sd = np.maximum(np.asarray(sd, float), 0.0)
        ds = np.diff(ss)
        denom = sd[:-1] + sd[1:]
        if np.any(denom <= 0.0):
            raise ArithmeticError("zero path speed over a whole interval")
        self._ss, self._sd = ss, sd
        self._sdd = (sd[1:] ** 2 - sd[:-1] ** 2) / (2.0 * ds)
        self._tt = np.r_[0.0, np.cumsum(2.0 * ds / denom)]
        self.duration = float(self._tt[-1])

    def state(self, t: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(s, sd, sdd) at times t (T,)."""
        t = np.clip(np.atleast_1d(np.asarray(t, float)), 0.0, self.duration)
        i = np.clip(np.searchsorted(self._tt, t, side="right") - 1, 0, len(self._sdd) - 1)
        tau = t - self._tt[i]
        sdd = self._sdd[i]
        s = np.minimum(self._ss[i] + self._sd[i] * tau + 0.5 * sdd * tau**2, self._ss[-1])
        return s, self._sd[i] + sdd * tau, sdd

    def __call__(self, t: FloatArray, order: int = 0) -> FloatArray:
        s, sd, sdd = self.state(t)
        if order == 0:
            return self.path(s)
        if order == 1:
            return self.path(s, 1) * sd[:, None]
        return self.path(s, 2) * (sd**2)[:, None] + self.path(s, 1) * sdd[:, None]


class _Hold:
    """A zero-length piece: the robot stays at q."""

    def __init__(self, q: FloatArray) -> None:
        self.q = q
        self.duration = 0.0

    def __call__(self, t: FloatArray, order: int = 0) -> FloatArray:
        t = np.atleast_1d(t)
        return np.tile(self.q if order == 0 else np.zeros_like(self.q), (t.shape[0], 1))


def _check_limits(limits: JointLimits) -> None:
    for what in ("velocity", "acceleration"):
        v = getattr(limits, what)
        if not np.all(np.isfinite(v) & (v > 0)):
            raise TimingError(f"{what} limits must be finite and > 0, got {v.tolist()}")


def _has_base(limits: JointLimits) -> bool:
    return limits.names[:3] == BASE_JOINTS


def _body_speeds(q: FloatArray, dq: FloatArray) -> FloatArray:
    """|base-frame velocity| (T, 2) from world-frame base x, y velocities and yaw."""
    c, s = np.cos(q[:, 2]), np.sin(q[:, 2])
    return np.abs(np.stack([c * dq[:, 0] + s * dq[:, 1], -s * dq[:, 0] + c * dq[:, 1]], axis=1))


def _worst_ratio(spline: ConstAccelPiece, limits: JointLimits, base: bool) -> tuple[float, float]:
    """The worst velocity and acceleration limit ratios over dense samples."""
    # evenly spaced samples, plus each gridpoint's left limit: PCHIP's second derivative jumps at
    # the waypoints, and the waypoints are gridpoints
    # CHECK_PER_INTERVAL in every gridpoint interval (evenly over the duration, a long interval was
    # sampled too coarsely to see its overshoot)
    tt = np.asarray(spline._tt, float)
    frac = np.arange(CHECK_PER_INTERVAL) / CHECK_PER_INTERVAL
    ts = np.r_[(tt[:-1, None] + np.diff(tt)[:, None] * frac).ravel(), tt[-1]]
    ts = np.r_[ts, np.maximum(tt[1:] - 1e-9, 0.0)]
    q, dq, ddq = spline(ts), spline(ts, 1), spline(ts, 2)
    v_ratio = np.abs(dq) / limits.velocity
    a_lim = limits.acceleration.copy()
    if base:
        v_ratio[:, :2] = _body_speeds(q, dq) / limits.velocity[:2]
        a_lim[:2] /= np.sqrt(2.0)
    return float(v_ratio.max()), float((np.abs(ddq) / a_lim).max())


@functools.lru_cache(maxsize=64)
def _constraints(v: tuple[float, ...], a: tuple[float, ...]) -> tuple:
    """TOPPRA's (velocity, acceleration, left-hand acceleration) constraints for these limits, built once:
    their constructors format the limit arrays into strings (a quarter of a retiming's time). They hold
    no per-path state, so instances are shared."""
    vv, aa = np.asarray(v), np.asarray(a)
    return (
        ta_con.JointVelocityConstraint(np.c_[-vv, vv]),
        ta_con.JointAccelerationConstraint(
            np.c_[-aa, aa], discretization_scheme=ta_con.DiscretizationType.Interpolation
        ),
        _LeftAcceleration(np.c_[-aa, aa], discretization_scheme=ta_con.DiscretizationType.Collocation),
    )


def _solve(path: PchipPath, limits: JointLimits, base: bool, gridpoints: int):
    v, a = limits.velocity, limits.acceleration.copy()
    if base:
        a[:2] /= np.sqrt(2.0)
        vb = v[:2]

        def vlim(s: float) -> FloatArray:
            q, dq = path(np.array([s]))[0], path(np.array([s]), 1)[0]
            c, sn = np.cos(q[2]), np.sin(q[2])
            body = np.abs([c * dq[0] + sn * dq[1], -sn * dq[0] + c * dq[1]])
            with np.errstate(divide="ignore"):
                sd_max = float(np.min(np.where(body > 1e-12, vb / body, np.inf)))
            out = np.c_[-v, v].astype(float)
            if np.isfinite(sd_max):
                out[:2, 1] = np.abs(dq[:2]) * sd_max + 1e-9
                out[:2, 0] = -out[:2, 1]
            return out

        pc_v = ta_con.JointVelocityConstraintVarying(vlim)
        _, pc_a, pc_a_left = _constraints(tuple(v), tuple(a))
    else:
        pc_v, pc_a, pc_a_left = _constraints(tuple(v), tuple(a))
    # PCHIP's second derivative jumps at the waypoints: each waypoint is a gridpoint, and TOPPRA must see
    # both one-sided values there. First try: a second gridpoint just before each waypoint. That tiny
    # interval can make the instance uncontrollable where a joint reverses; second: the left-hand value
    # as a collocated constraint at the waypoint; last: the waypoints alone (verification catches the rest).
    inner = path.waypoints[0][1:-1]
    uniform = np.linspace(0.0, 1.0, max(gridpoints + 1 - 2 * len(inner), 2))
    tries = (
        (np.r_[uniform, inner, inner - 1e-6], [pc_v, pc_a]),
        (np.r_[uniform, inner], [pc_v, pc_a, pc_a_left]),
        (np.r_[uniform, inner], [pc_v, pc_a]),
    )
    for grid, constraints in tries:
        grid = np.unique(grid)
        grid = grid[np.r_[True, np.diff(grid) > 1e-9]]
        inst = ta_algo.TOPPRA(constraints, path, gridpoints=grid, solver_wrapper="seidel")
        inst.compute_parameterization(0.0, 0.0)
        data = inst.problem_data
        if data.return_code == ta_algo.ParameterizationReturnCode.Ok and data.sd_vec is not None:
            break
    else:
        return None
    return ConstAccelPiece(path, np.asarray(data.gridpoints), np.asarray(data.sd_vec))


def cusps(p: FloatArray, max_turn_deg: float = CUSP_DEG) -> list[int]:
    """Interior waypoints of ``p`` (T, N) where the path turns by more than ``max_turn_deg``."""
    d = np.diff(p, axis=0)
    n = np.linalg.norm(d, axis=1)
    cos = np.einsum("ij,ij->i", d[:-1], d[1:]) / np.maximum(n[:-1] * n[1:], 1e-300)
    return [int(i) + 1 for i in np.flatnonzero(cos < math.cos(math.radians(max_turn_deg)))]


def densify(p: FloatArray, step: float) -> FloatArray:
    """The polyline ``p`` (T, N) with two points inserted on each segment, ``step`` (per joint, at most)
    from its ends.

    The planners hand over straight segments, checked for collisions as straight segments. A cubic
    per joint through sparse waypoints leaves them: PCHIP flattens each joint at its own turning
    points, so joints fall out of step along a long segment (an arm finishing its motion while the base
    still turns: tens of centimetres off the checked path). PCHIP reproduces collinear data, so with
    points ``step`` from each end the cubic is exact between them and leaves the segment only in the
    short intervals at a corner, by a fraction of ``step``; a short segment is cut into thirds."""
    out = [p[:1]]
    for a, b in itertools.pairwise(p):
        f = min(step / max(float(np.abs(b - a).max()), 1e-300), 1.0 / 3.0)
        out.append(a[None] + np.array([f, 1.0 - f, 1.0])[:, None] * (b - a)[None])
    return np.vstack(out)


def time_parameterize(
    path: Sequence[Sequence[float]] | FloatArray, limits: JointLimits, *, gridpoints: int = 100
) -> TimingResult:
    """Retime one phase path (T, N) rest-to-rest. Bad input raises TimingError; failures are statuses."""
    t0 = time.perf_counter()
    _check_limits(limits)
    if not (isinstance(gridpoints, int) and gridpoints >= 2):
        raise TimingError(f"gridpoints must be an integer >= 2, got {gridpoints!r}")
    p = limits.unwrap(as_path(path, limits))
    keep = np.r_[True, np.linalg.norm(np.diff(p, axis=0), axis=1) > _DUP]
    p = p[keep]
    if p.shape[0] == 1:  # nothing moves
        traj = Trajectory(limits.names, limits, (_Hold(p[0]),), (Segment(PhaseKind.MOTION, 0.0, 0.0),))
        return TimingResult(TimingStatus.OK, "no motion", traj, (time.perf_counter() - t0) * 1e3)
    res = _time_path(densify(p, DENSIFY_STEP), limits, base=_has_base(limits), gridpoints=gridpoints, t0=t0)
    corners = cusps(p) if res.status in (TimingStatus.INFEASIBLE, TimingStatus.NUMERICAL) else []
    if corners:  # a path reversing at a waypoint (a vertical approach then leave) may have no smooth
        # timing through that corner: stop there, i.e. time the pieces between sharp corners rest-to-rest
        cuts = [0, *corners, p.shape[0] - 1]
        return time_parameterize_phases(
            [(PhaseKind.MOTION, p[a : b + 1]) for a, b in itertools.pairwise(cuts)], limits, gridpoints=gridpoints
        )
    return res


def _time_path(p: FloatArray, limits: JointLimits, *, base: bool, gridpoints: int, t0: float) -> TimingResult:
    """TOPPRA on one PCHIP path through the (deduplicated, unwrapped) waypoints ``p`` (T, N)."""
    chord = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))]
    spline_path = PchipPath(chord / chord[-1], p)
    ss = np.linspace(0.0, 1.0, 2001)
    q_path = spline_path(ss)
    over = np.maximum(limits.lower - q_path, q_path - limits.upper).max(axis=0)
    if np.any(over > POSITION_TOLERANCE):
        bad = [limits.names[i] for i in np.flatnonzero(over > POSITION_TOLERANCE)]
        return TimingResult(
            TimingStatus.LIMIT_VIOLATION,
            f"the interpolated path leaves the position limits of {bad}",
            compute_ms=(time.perf_counter() - t0) * 1e3,
        )
    try:
        spline = _solve(spline_path, limits, base, gridpoints)
    except (ValueError, ArithmeticError, np.linalg.LinAlgError) as e:
        return TimingResult(
            TimingStatus.NUMERICAL,
            f"TOPPRA failed: {type(e).__name__}: {e}",
            compute_ms=(time.perf_counter() - t0) * 1e3,
        )
    if spline is None:
        return TimingResult(
            TimingStatus.INFEASIBLE,
            "TOPPRA found no parameterisation under the limits",
            compute_ms=(time.perf_counter() - t0) * 1e3,
        )
    if not np.isfinite(spline.duration) or spline.duration <= 0.0:
        return TimingResult(
            TimingStatus.NUMERICAL,
            f"TOPPRA returned duration {spline.duration}",
            compute_ms=(time.perf_counter() - t0) * 1e3,
        )
    for attempt in range(MAX_RETRIES + 1):
        rv, ra = _worst_ratio(spline, limits, base)
        if max(rv, ra) <= 1.0 + 1e-6:
            traj = Trajectory(
                limits.names, limits, (spline,), (Segment(PhaseKind.MOTION, 0.0, float(spline.duration)),)
            )
            return TimingResult(TimingStatus.OK, "ok", traj, (time.perf_counter() - t0) * 1e3, attempt)
        # slow the whole motion down by c: velocities scale by 1/c and accelerations by 1/c^2, exactly
        c = max(rv, math.sqrt(ra), 1.0) * 1.0005
        log.debug("TOPPRA overshoot (v %.4f, a %.4f): stretching time by %.4f", rv, ra, c)
        spline = ConstAccelPiece(spline.path, spline._ss, spline._sd / c)
    return TimingResult(
        TimingStatus.LIMIT_VIOLATION,
        f"limits still exceeded (v x{rv:.4f}, a x{ra:.4f}) after {MAX_RETRIES} time stretches",
        compute_ms=(time.perf_counter() - t0) * 1e3,
        retries=MAX_RETRIES,
    )


def time_parameterize_phases(
    phases: Sequence[tuple[PhaseKind, Sequence[Sequence[float]] | FloatArray]],
    limits: JointLimits,
    *,
    gridpoints: int = 100,
    continuity_tolerance: float = 1e-6,
) -> TimingResult:
    """Retime consecutive phases separately (each rest-to-rest) into one piece-wise trajectory.

    Gripper and articulated phases stay their own segments, so the executive knows where each starts.
    Consecutive phases must meet: the last waypoint of one is the first of the next.
    """
    if not phases:
        raise TimingError("no phases to parameterise")
    t0 = time.perf_counter()
    pieces: list[_Spline] = []
    segments: list[Segment] = []
    t, retries = 0.0, 0
    prev_end: FloatArray | None = None
    for i, (kind, path) in enumerate(phases):
        if not isinstance(kind, PhaseKind):
            raise TimingError(
                f"phase {i}: kind must be a PhaseKind, got {kind!r}; valid: {[k.name for k in PhaseKind]}"
            )
        p = as_path(path, limits)
        if prev_end is not None:
            gap = np.abs(limits.difference(p[0], prev_end)).max()
            if gap > continuity_tolerance:
                raise TimingError(f"phase {i} starts {gap:.3g} away from where phase {i - 1} ends")
        res = time_parameterize(p, limits, gridpoints=gridpoints)
        if not res.ok:
            return TimingResult(
                res.status,
                f"phase {i} ({kind.value}): {res.reason}",
                compute_ms=(time.perf_counter() - t0) * 1e3,
                retries=retries + res.retries,
            )
        assert res.trajectory is not None
        retries += res.retries
        for piece in res.trajectory.pieces:  # several when the phase stops at sharp corners
            if pieces:  # keep the unwrapped angles continuous from one phase to the next
                last = pieces[-1](np.array([pieces[-1].duration]))[0]
                first = piece(np.array([0.0]))[0]
                shift = np.round((last - first) / (2 * np.pi)) * 2 * np.pi * limits.continuous
                if np.any(shift):
                    piece = _Shifted(piece, shift)
            pieces.append(piece)
            segments.append(Segment(kind, t, t + piece.duration))
            t += piece.duration
        prev_end = p[-1]
    traj = Trajectory(limits.names, limits, tuple(pieces), tuple(segments))
    return TimingResult(TimingStatus.OK, "ok", traj, (time.perf_counter() - t0) * 1e3, retries)


class _Shifted:
    """A piece whose positions are offset by whole turns on continuous joints."""

    def __init__(self, piece: _Spline, shift: FloatArray) -> None:
        self.piece, self.shift, self.duration = piece, shift, piece.duration

    def __call__(self, t: FloatArray, order: int = 0) -> FloatArray:
        out = self.piece(t, order)
        return out + self.shift if order == 0 else out
