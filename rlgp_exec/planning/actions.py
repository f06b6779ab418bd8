"""The action kinds R-LGP's geometric layers realise, defined once: each kind's symbolic name, what its
target is, and what it does to the world (which object it moves, whether it lets one go). The layers
(``rlgp.to_actions``/``_site``, the keyframe NLP, the object poses, the replay phases) read these sets
instead of spelling out kind names each.

``stack`` sets the held object down on a support: a region (a slot), like ``place``, or a movable
object, on its top face wherever an earlier action of the plan left it (the symbolic layer has already
required it clear and ``stackable``).
"""

from __future__ import annotations

from typing import NamedTuple

from rlgp_exec.errors import RlgpError

__all__ = ["ACTION_KINDS", "GEOMETRIC_ACTIONS", "MOVES_OBJECT", "RELEASES", "SETS_DOWN", "ActionKind", "kind"]


class ActionKind(NamedTuple):
    name: str  # the symbolic action's name (the PDDL domain's)
    target: str  # what the target argument is: "none", "surface" (region/fixture/movable), "cabinet"
    moves_object: bool  # its keyframe moves or lets go of an object (the object is not an obstacle there)
    releases: bool  # the hand lets the object go at its keyframe
    sets_down: bool  # the released object rests where the hand put it (a drop falls instead)


ACTION_KINDS: tuple[ActionKind, ...] = (
    ActionKind("pick", "none", True, False, False),
    ActionKind("place", "surface", True, True, True),
    ActionKind("stack", "surface", True, True, True),
    ActionKind("drop", "cabinet", True, True, False),
    ActionKind("take_knob", "none", False, False, False),
    ActionKind("open_drawer", "none", False, False, False),
    ActionKind("close_drawer", "none", False, False, False),
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
