"""Drop: the held object is let go above an open drawer of a cabinet and falls into it."""

from __future__ import annotations

from rlgp_exec.planning.actions.kind import ActionKind, Kind

__all__ = ["DROP"]

DROP = ActionKind(Kind.DROP, "cabinet", True, True, False)
