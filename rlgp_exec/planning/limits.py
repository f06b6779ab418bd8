"""Planner limits: the CPU-time budget and the search's expansion cap a caller (``plan``, ``run``,
``daemon``, ``bench``) hands every planner through ``registry.plan``.

``None`` in a field leaves that planner's own default: R-LGP ``TIME_BUDGET_S`` and 20 000 expansions of its
symbolic search; GNPP ``BENCH_TIMEOUT_S`` and 200 000 expansions of its logic search per iteration.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rlgp_exec.errors import RlgpError

__all__ = ["DEFAULT_LIMITS", "PlanLimits"]


@dataclass(frozen=True)
class PlanLimits:
    """``time_budget_s`` [s] of CPU time per planning call; ``max_expansions`` of the symbolic search."""

    time_budget_s: float | None = None
    max_expansions: int | None = None

    def __post_init__(self) -> None:
        t = self.time_budget_s
        if t is not None and (isinstance(t, bool) or not isinstance(t, int | float) or not math.isfinite(t) or t <= 0):
            raise RlgpError(f"time budget {t!r} s: must be a positive number of seconds (CPU time per plan)")
        n = self.max_expansions
        if n is not None and (isinstance(n, bool) or not isinstance(n, int) or n < 1):
            raise RlgpError(f"max expansions {n!r}: must be a positive whole number of search expansions")

    def as_dict(self) -> dict[str, float | int | None]:
        return {"time_budget_s": self.time_budget_s, "max_expansions": self.max_expansions}


DEFAULT_LIMITS = PlanLimits()
