"""The drawer actions: take a cabinet's knob, then open or close its drawer with the hand on it."""

from __future__ import annotations

from rlgp_exec.planning.actions.kind import ActionKind, Kind

__all__ = ["CLOSE_DRAWER", "DRAWER_ACTIONS", "DRIVES", "OPEN_DRAWER", "TAKE_KNOB", "opening_after"]

TAKE_KNOB = ActionKind(Kind.TAKE_KNOB, "none", False, False, False)
OPEN_DRAWER = ActionKind(Kind.OPEN_DRAWER, "none", False, False, False)
CLOSE_DRAWER = ActionKind(Kind.CLOSE_DRAWER, "none", False, False, False)
#: the kinds whose object is a cabinet, at whose knob the hand is
DRAWER_ACTIONS = (Kind.TAKE_KNOB, Kind.OPEN_DRAWER, Kind.CLOSE_DRAWER)
#: the kinds in which the hand on the knob drives the drawer
DRIVES = (Kind.OPEN_DRAWER, Kind.CLOSE_DRAWER)


def opening_after(name: str, travel: float) -> float:
    """[m] the drawer's opening after a drive ``name`` of a drawer that travels ``travel`` [m]."""
    return travel if name == Kind.OPEN_DRAWER else 0.0
