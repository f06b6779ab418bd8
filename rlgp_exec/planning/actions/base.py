"""GNPP's base moves (the paper's move operators): ``start-move`` lets a mobile arm's base move (the hand
lifted), ``end-move`` drives it to the base of the keyframes that follow. R-LGP moves the base within its
keyframes instead, so its plans have none."""

from __future__ import annotations

from rlgp_exec.planning.actions.kind import ActionKind, Kind

__all__ = ["END_MOVE", "MOVES", "START_MOVE"]

START_MOVE = ActionKind(Kind.START_MOVE, "none", False, False, False, rlgp=False, has_object=False)
END_MOVE = ActionKind(Kind.END_MOVE, "none", False, False, False, rlgp=False, has_object=False)
#: the move operators, in their order in a plan
MOVES = (Kind.START_MOVE, Kind.END_MOVE)
