"""Timing results as values: status codes, trajectories and their segments."""

from __future__ import annotations

import enum
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from rlgp_exec.errors import RlgpError
from rlgp_exec.robot.limits import JointLimits

__all__ = ["PhaseKind", "Segment", "TimingError", "TimingResult", "TimingStatus", "Trajectory"]

FloatArray = NDArray[np.float64]


class TimingError(RlgpError):
    """Bad input to the timing layer (empty path, NaN, bad limits, shape mismatch)."""


class TimingStatus(enum.Enum):
    """Expected outcomes of time-parameterisation (toppra's return codes, our words)."""

    OK = "ok"
    INFEASIBLE = "infeasible"  # TOPPRA found no parameterisation under the limits
    LIMIT_VIOLATION = "limit_violation"  # the result breaks the limits beyond tolerance after retries
    NUMERICAL = "numerical"  # NaN or a solver failure inside the dependency


class PhaseKind(enum.Enum):
    MOTION = "motion"  # arm/base motion between mode switches
    GRIPPER = "gripper"  # opening/closing the hand
    ARTICULATED = "articulated"  # moving with an articulated object (a drawer)


class _Spline(Protocol):
    duration: float

    def __call__(self, t: FloatArray, order: int = 0) -> FloatArray: ...


@dataclass(frozen=True)
class Segment:
    """One parameterised phase inside a trajectory: [t_start, t_end] [s]."""

    kind: PhaseKind
    t_start: float
    t_end: float


@dataclass(frozen=True, eq=False)
class Trajectory:
    """A time-parameterised joint trajectory, piece-wise over phases.

    Positions are kept unwrapped internally (continuous joints move through ±pi without jumps);
    :meth:`sample` returns them wrapped to [-pi, pi) when ``wrap`` is True.
    """

    names: tuple[str, ...]
    limits: JointLimits
    pieces: tuple[_Spline, ...]
    segments: tuple[Segment, ...]

    @property
    def duration(self) -> float:
        """Total duration [s]."""
        return self.segments[-1].t_end if self.segments else 0.0

    @property
    def dof(self) -> int:
        return len(self.names)

    def _piece(self, t: float) -> tuple[int, float]:
        t = min(max(t, 0.0), self.duration)
        for i, seg in enumerate(self.segments):
            if t <= seg.t_end or i == len(self.segments) - 1:
                return i, t - seg.t_start
        raise AssertionError("unreachable")

    def sample(self, t: float, wrap: bool = True) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(q, dq, ddq), each (N,), at time ``t`` [s] (clamped to [0, duration])."""
        i, tau = self._piece(float(t))
        sp = self.pieces[i]
        tau = min(tau, sp.duration)
        q, dq, ddq = (np.asarray(sp(np.array([tau]), k))[0] for k in (0, 1, 2))
        if t >= self.duration:  # holding the end: at rest
            dq, ddq = np.zeros_like(dq), np.zeros_like(ddq)
        return (self.limits.wrap(q) if wrap else q), dq, ddq

    def sample_many(self, ts: FloatArray, wrap: bool = True) -> tuple[FloatArray, FloatArray, FloatArray]:
        """(q, dq, ddq), each (T, N), at times ``ts`` (T,) [s], vectorised per piece."""
        ts = np.clip(np.asarray(ts, dtype=float).reshape(-1), 0.0, self.duration)
        out = [np.zeros((ts.shape[0], self.dof)) for _ in range(3)]
        ends = np.array([seg.t_end for seg in self.segments])
        idx = np.minimum(np.searchsorted(ends, ts, side="left"), len(self.segments) - 1)
        for i, (seg, sp) in enumerate(zip(self.segments, self.pieces, strict=True)):
            m = idx == i
            if not np.any(m):
                continue
            tau = np.minimum(ts[m] - seg.t_start, sp.duration)
            for k in range(3):
                out[k][m] = sp(tau, k)
        at_end = ts >= self.duration
        out[1][at_end] = 0.0
        out[2][at_end] = 0.0
        q = self.limits.wrap(out[0]) if wrap else out[0]
        return q, out[1], out[2]

    def sample_rate(self, hz: float, wrap: bool = True) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
        """(t (T,), q (T, N), dq (T, N), ddq (T, N)) at a fixed rate, the last sample at the end."""
        if not (hz > 0.0 and np.isfinite(hz)):
            raise TimingError(f"sample rate must be a positive number of Hz, got {hz}")
        ts = np.arange(0.0, self.duration, 1.0 / hz)
        ts = np.append(ts, self.duration)
        return (ts, *self.sample_many(ts, wrap))

    def end(self, wrap: bool = True) -> FloatArray:
        return self.sample(self.duration, wrap)[0]


@dataclass(frozen=True)
class TimingResult:
    """What :func:`~rlgp_exec.timing.toppra_param.time_parameterize` returns: never an exception
    for an expected failure; ``trajectory`` is None unless ``status`` is OK."""

    status: TimingStatus
    reason: str
    trajectory: Trajectory | None = None
    compute_ms: float = 0.0
    retries: int = 0

    @property
    def ok(self) -> bool:
        return self.status is TimingStatus.OK


def as_path(path: Sequence[Sequence[float]] | FloatArray, limits: JointLimits) -> FloatArray:
    """Validate a (T, N) waypoint array against ``limits`` (bad input raises TimingError)."""
    try:
        p = np.array(path, dtype=float)
    except (TypeError, ValueError) as e:
        raise TimingError(f"path is not a numeric (T, N) array: {e}") from None
    if p.ndim != 2 or p.shape[1] != limits.n:
        raise TimingError(f"path must have shape (T, {limits.n}) for joints {list(limits.names)}, got {p.shape}")
    if p.shape[0] < 2:
        raise TimingError(f"path needs at least 2 waypoints, got {p.shape[0]}")
    if not np.all(np.isfinite(p)):
        rows = sorted(set(np.argwhere(~np.isfinite(p))[:, 0].tolist()))
        raise TimingError(f"path has NaN/inf values in waypoint(s) {rows[:10]}")
    return p
