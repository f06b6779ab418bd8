"""Stack: the held object is set down on a support, a region (a slot) like ``place``, or a movable object,
on its top face wherever an earlier action of the plan left it (the symbolic layer has already required it
clear and ``stackable``)."""

from __future__ import annotations

from rlgp_exec.planning.actions.kind import ActionKind, Kind

__all__ = ["STACK"]

STACK = ActionKind(Kind.STACK, "surface", True, True, True)
