"""The planners' budget clock: CPU time, not wall time.

Both papers report CPU time; a wall-clock budget on a shared machine measures its load (the same
planner, given fewer cycles, would try fewer candidates and fail more). Children count once they
have finished (Fast Downward runs as one)."""

from __future__ import annotations

import os

__all__ = ["cpu_clock"]


def cpu_clock() -> float:
    """CPU time [s] of this process and of its finished children (user + system)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system
