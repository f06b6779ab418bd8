"""The project's exception hierarchy: one root, a few families.

Expected failures (an infeasible plan, a TOPPRA failure, a rejected payload) are status values,
not exceptions. Exceptions are for real errors: bad input that cannot be acted on, a broken
model, a misused API. Every message names what is wrong and, where there is a choice, the
valid options.
"""

from __future__ import annotations

__all__ = [
    "ModelError",
    "RlgpError",
    "SceneError",
]


class RlgpError(Exception):
    """Root of every error this project raises on purpose."""


class ModelError(RlgpError):
    """A robot model could not be built or was used with a wrong name, shape or value."""


class SceneError(RlgpError):
    """A scene file (or scene dict) is invalid.

    The message always names the source (file), the table and the field, e.g.
    ``sorting_pr2.toml: [[object]] 'block_blue'.size: expected 3 positive numbers, got [0.05, -1]``.
    """

    def __init__(self, source: str, where: str, message: str) -> None:
        self.source = source
        self.where = where
        self.detail = message
        super().__init__(f"{source}: {where}: {message}")
