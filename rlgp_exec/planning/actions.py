"""The action kinds R-LGP's geometric layers realise, defined once: each kind's symbolic name, what its
target is, and what it does to the world (which object it moves, whether it lets one go). The layers
(``rlgp.to_actions``/``_site``, the keyframe NLP, the object poses, the replay phases) read these sets
instead of spelling out kind names each.

``stack`` sets the held object down on a support: a region (a slot), like ``place``, or a movable
object, on its top face wherever an earlier action of the plan left it (the symbolic layer has already
required it clear and ``stackable``).
"""

from __future__ import annotations

import enum
from typing import NamedTuple

from rlgp_exec.errors import RlgpError

__all__ = ["ACTION_KINDS", "GEOMETRIC_ACTIONS", "MOVES_OBJECT", "RELEASES", "SETS_DOWN", "ActionKind", "Kind", "kind"]


class Kind(enum.StrEnum):
    """An action kind's name, as the PDDL domain and the plans spell it (a str: ``Kind.PICK == "pick"``)."""

    PICK = "pick"
    PLACE = "place"
    STACK = "stack"
    DROP = "drop"
    TAKE_KNOB = "take_knob"
    OPEN_DRAWER = "open_drawer"
    CLOSE_DRAWER = "close_drawer"


class ActionKind(NamedTuple):
    name: Kind  # the symbolic action's name (the PDDL domain's)
    target: str  # what the target argument is: "none", "surface" (region/fixture/movable), "cabinet"
    moves_object: bool  # its keyframe moves or lets go of an object (the object is not an obstacle there)
    releases: bool  # the hand lets the object go at its keyframe
    sets_down: bool  # the released object rests where the hand put it (a drop falls instead)


ACTION_KINDS: tuple[ActionKind, ...] = (
    ActionKind(Kind.PICK, "none", True, False, False),
    ActionKind(Kind.PLACE, "surface", True, True, True),
    ActionKind(Kind.STACK, "surface", True, True, True),
    ActionKind(Kind.DROP, "cabinet", True, True, False),
    ActionKind(Kind.TAKE_KNOB, "none", False, False, False),
    ActionKind(Kind.OPEN_DRAWER, "none", False, False, False),
    ActionKind(Kind.CLOSE_DRAWER, "none", False, False, False),
)
GEOMETRIC_ACTIONS = tuple(k.name for k in ACTION_KINDS)
MOVES_OBJECT = frozenset(k.name for k in ACTION_KINDS if k.moves_object)
RELEASES = frozenset(k.name for k in ACTION_KINDS if k.releases)
SETS_DOWN = frozenset(k.name for k in ACTION_KINDS if k.sets_down)


def kind(name: str) -> ActionKind:
    """The kind called ``name``; RlgpError naming the valid kinds otherwise."""
    for k in ACTION_KINDS:
        if k.name == name:
            return k
    raise RlgpError(f"unknown action kind {name!r}; valid: {list(GEOMETRIC_ACTIONS)}")
