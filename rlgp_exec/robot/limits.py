"""Joint limits as one immutable value object, shared by planning, timing and the executive."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from rlgp_exec.errors import ModelError

__all__ = ["JointLimits", "wrap_angle"]

FloatArray = NDArray[np.float64]

#: ``JointLimits.continuous`` when not given: no continuous joints (n False flags after construction)
_NO_CONTINUOUS: NDArray[np.bool_] = np.zeros(0, bool)


def wrap_angle(a: ArrayLike) -> FloatArray:
    """Wrap angles [rad] into [-pi, pi)."""
    x = np.asarray(a, dtype=float)
    return (x + np.pi) % (2.0 * np.pi) - np.pi


def _frozen(a: ArrayLike, n: int, what: str) -> FloatArray:
    x = np.array(a, dtype=float).reshape(-1)
    if x.shape != (n,):
        raise ModelError(f"JointLimits.{what}: expected {n} values, got {x.shape[0]}")
    x.setflags(write=False)
    return x


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Position, velocity, acceleration and jerk limits of an ordered set of joints.

    All arrays have shape (N,), in SI units: [m] or [rad] for positions, then per second.
    Continuous joints (the base yaw, PR2 roll joints) have ``lower=-inf, upper=+inf`` and
    ``continuous=True``; their positions are angles to be wrapped to [-pi, pi).
    For the planar base the first three entries are x, y [m] and yaw [rad] in the world frame;
    the velocity limits of x and y hold along the base frame's axes (an omnidirectional base).
    """

    names: tuple[str, ...]
    lower: FloatArray
    upper: FloatArray
    velocity: FloatArray
    acceleration: FloatArray
    jerk: FloatArray
    continuous: NDArray[np.bool_] = field(default_factory=lambda: _NO_CONTINUOUS)

    def __post_init__(self) -> None:
        n = len(self.names)
        if len(set(self.names)) != n:
            raise ModelError(f"JointLimits: duplicate joint names in {list(self.names)}")
        for what in ("lower", "upper", "velocity", "acceleration", "jerk"):
            object.__setattr__(self, what, _frozen(getattr(self, what), n, what))
        given = self.continuous is not None and self.continuous is not _NO_CONTINUOUS
        cont = np.array(self.continuous, bool) if given else np.zeros(n, bool)
        if cont.shape != (n,):
            raise ModelError(f"JointLimits.continuous: expected {n} flags, got {cont.shape}")
        cont.setflags(write=False)
        object.__setattr__(self, "continuous", cont)
        for what in ("velocity", "acceleration", "jerk"):
            v = getattr(self, what)
            bad = [self.names[i] for i in np.flatnonzero(~(v > 0.0) | ~np.isfinite(v))]
            if bad:
                raise ModelError(f"JointLimits.{what}: must be finite and > 0 for every joint; bad: {bad}")
        bad = [self.names[i] for i in np.flatnonzero(~(self.lower < self.upper))]
        if bad:
            raise ModelError(f"JointLimits: lower must be < upper; bad: {bad}")

    @property
    def n(self) -> int:
        return len(self.names)

    def index(self, names: Sequence[str]) -> list[int]:
        """Positions of ``names`` in this set; unknown names raise with the valid options."""
        lookup = {nm: i for i, nm in enumerate(self.names)}
        missing = [nm for nm in names if nm not in lookup]
        if missing:
            raise ModelError(f"unknown joint(s) {missing}; valid: {list(self.names)}")
        return [lookup[nm] for nm in names]

    def subset(self, names: Sequence[str]) -> JointLimits:
        """The limits of ``names``, in that order."""
        idx = self.index(names)
        return JointLimits(
            names=tuple(names),
            lower=self.lower[idx],
            upper=self.upper[idx],
            velocity=self.velocity[idx],
            acceleration=self.acceleration[idx],
            jerk=self.jerk[idx],
            continuous=self.continuous[idx],
        )

    def scaled(self, velocity: float = 1.0, acceleration: float = 1.0, jerk: float = 1.0) -> JointLimits:
        """Limits scaled down, e.g. ``scaled(0.5, 0.5)`` for a first run on hardware at 50 % speed."""
        for what, s in (("velocity", velocity), ("acceleration", acceleration), ("jerk", jerk)):
            if not (0.0 < s <= 1.0):
                raise ModelError(f"JointLimits.scaled: {what} factor must be in (0, 1], got {s}")
        return JointLimits(
            names=self.names,
            lower=self.lower,
            upper=self.upper,
            velocity=self.velocity * velocity,
            acceleration=self.acceleration * acceleration,
            jerk=self.jerk * jerk,
            continuous=self.continuous,
        )

    def wrap(self, q: ArrayLike) -> FloatArray:
        """``q`` (..., N) with continuous joints wrapped to [-pi, pi)."""
        out = np.array(q, dtype=float)
        out[..., self.continuous] = wrap_angle(out[..., self.continuous])
        return out

    def difference(self, q1: ArrayLike, q0: ArrayLike) -> FloatArray:
        """``q1 - q0`` (..., N), taking the short way round on continuous joints."""
        d = np.asarray(q1, dtype=float) - np.asarray(q0, dtype=float)
        d[..., self.continuous] = wrap_angle(d[..., self.continuous])
        return d

    def unwrap(self, path: ArrayLike) -> FloatArray:
        """A path (T, N) with continuous joints made continuous (no 2*pi jumps between rows)."""
        p = np.array(path, dtype=float)
        if p.ndim != 2 or p.shape[1] != self.n:
            raise ModelError(f"JointLimits.unwrap: expected a (T, {self.n}) path, got {p.shape}")
        if self.continuous.any():
            p[:, self.continuous] = np.unwrap(p[:, self.continuous], axis=0)
        return p

    def within(self, q: ArrayLike, tol: float = 0.0) -> bool:
        """True when ``q`` (N,) is within position limits (continuous joints always are)."""
        x = np.asarray(q, dtype=float)
        return bool(np.all(x >= self.lower - tol) and np.all(x <= self.upper + tol))

    def clip(self, q: ArrayLike) -> FloatArray:
        """``q`` clipped to the position limits, continuous joints wrapped."""
        return np.clip(self.wrap(q), self.lower, self.upper)
