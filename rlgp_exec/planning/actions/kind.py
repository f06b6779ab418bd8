"""What every action kind is: its name (``Kind``, one vocabulary for both planners, the executive, the
replay and the plot), its definition (``ActionKind``), and how an action is written (``action_text``).

A kind's ground arguments follow the PDDL domain: the manipulator first, then the object (the cabinet
for the drawer actions), then the target or support; GNPP's base moves take the manipulator only.
"""

from __future__ import annotations

import enum
from collections.abc import Sequence
from typing import NamedTuple

__all__ = ["ActionKind", "Kind", "action_text", "describe", "named_arm"]


class Kind(enum.StrEnum):
    """An action kind's name, as the PDDL domain and the plans spell it (a str: ``Kind.PICK == "pick"``)."""

    PICK = "pick"
    PLACE = "place"
    STACK = "stack"
    DROP = "drop"
    TAKE_KNOB = "take_knob"
    OPEN_DRAWER = "open_drawer"
    CLOSE_DRAWER = "close_drawer"
    PICK_FROM_DRAWER = "pick_from_drawer"
    START_MOVE = "start-move"
    END_MOVE = "end-move"


class ActionKind(NamedTuple):
    name: Kind  # the symbolic action's name (the PDDL domain's)
    target: str  # what the target argument is: "none", "surface" (region/fixture/movable), "cabinet"
    moves_object: bool  # its keyframe moves or lets go of an object (the object is not an obstacle there)
    releases: bool  # the hand lets the object go at its keyframe
    sets_down: bool  # the released object rests where the hand put it (a drop falls instead)
    rlgp: bool = True  # R-LGP's geometric layers realise it
    gnpp: bool = True  # GNPP's graph-NLP has factors for it (``gnpp.pntc``, ``gnpp.drawer_pntc``)
    has_object: bool = True  # its second ground argument is an object or cabinet (a base move has none)


def action_text(name: str, obj: str | None, target: str | None = None, arm: str | None = None) -> str:
    """An action as both planners' ``Plan.actions`` write it: ``(name [arm] [obj] [target])``, e.g.
    ``(pick block)``, ``(place right_arm block tray)``, ``(start-move)``. The arm is named only when the
    robot has more than one (the caller passes None otherwise); a pick names no support (where the object
    was is the state's, not the action's)."""
    return f"({' '.join(w for w in (str(name), arm, obj, target) if w)})"


def named_arm(arms: Sequence[str], arm: str) -> str | None:
    """``arm`` if the robot's manipulators ``arms`` are more than one (the name then says which), else None."""
    return arm if len(arms) > 1 else None


def describe(k: ActionKind, args: Sequence[str], name_arm: bool) -> str:
    """``action_text`` of a ground action of kind ``k`` with the PDDL domain's ``args``."""
    obj = args[1] if k.has_object and len(args) > 1 else None
    target = args[2] if k.target != "none" and len(args) > 2 else None
    return action_text(k.name, obj, target, args[0] if name_arm and args else None)
