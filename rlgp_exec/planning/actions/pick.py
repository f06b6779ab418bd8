"""Pick: the hand grasps an object off its support (a region, a fixture or a movable) and holds it.
``pick_from_drawer`` takes it out of an open drawer (the symbolic layer's; no planner realises it yet)."""

from __future__ import annotations

from rlgp_exec.planning.actions.kind import ActionKind, Kind

__all__ = ["PICK", "PICKS", "PICK_FROM_DRAWER"]

PICK = ActionKind(Kind.PICK, "none", True, False, False)
PICK_FROM_DRAWER = ActionKind(Kind.PICK_FROM_DRAWER, "none", True, False, False, rlgp=False, gnpp=False)
#: the kinds after which the hand holds the object
PICKS = frozenset({Kind.PICK, Kind.PICK_FROM_DRAWER})
