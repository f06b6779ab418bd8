"""The symbolic layer's error: bad goals, bad literals, malformed PDDL, misuse of the API.

Expected failures (no plan, a Fast Downward timeout) are status values, not exceptions.
"""

from __future__ import annotations

from rlgp_exec.errors import RlgpError

__all__ = ["SymbolicError"]


class SymbolicError(RlgpError):
    """A symbolic problem, domain or plan is invalid; the message names it and the valid options."""
