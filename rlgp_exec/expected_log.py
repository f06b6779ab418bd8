"""Warnings a caller provoked on purpose, logged at INFO: a bench that injects faults expects the
executive's and the HAL's warnings about them (an e-stop latched, a stale state), and an operator reading
the log should not take them for trouble.
"""

from __future__ import annotations

import contextlib
import logging
from collections.abc import Iterator, Sequence

__all__ = ["expected_warnings"]


class _Downgrade(logging.Filter):
    def __init__(self, logger: logging.Logger) -> None:
        super().__init__()
        self.logger = logger

    def filter(self, record: logging.LogRecord) -> bool:
        if record.levelno == logging.WARNING:
            record.levelno, record.levelname = logging.INFO, "INFO"
            return self.logger.isEnabledFor(logging.INFO)
        return True


@contextlib.contextmanager
def expected_warnings(loggers: Sequence[str]) -> Iterator[None]:
    """Inside the block, WARNING records of ``loggers`` (each by its exact name) become INFO records (and are
    dropped where INFO is not enabled); errors stay errors."""
    filters = [(lg, _Downgrade(lg)) for lg in map(logging.getLogger, loggers)]
    for lg, f in filters:
        lg.addFilter(f)
    try:
        yield
    finally:
        for lg, f in filters:
            lg.removeFilter(f)
