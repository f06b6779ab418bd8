"""Polling for a condition in tests that watch threads, processes or a network (generous deadlines, no
fixed sleeps as assertions)."""

from __future__ import annotations

import time
from collections.abc import Callable


def wait_for(pred: Callable[[], object], timeout: float = 3.0, step: float = 0.005) -> bool:
    """Whether ``pred()`` became true within ``timeout`` [s], polled every ``step`` [s] (and once more at the end)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(step)
    return bool(pred())
