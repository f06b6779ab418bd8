"""The action kinds, defined once for both planners (one module per kind: ``pick``, ``place``, ``stack``,
``drop``, ``drawer``, ``base``): each kind's symbolic name, what its target is, and what it does to the
world (which object it moves, whether it lets one go). R-LGP's layers (``rlgp.to_actions``/``_site``, the
keyframe NLP, the object poses, the replay phases) and GNPP read these instead of spelling kind names.
"""

from __future__ import annotations

from typing import NamedTuple

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions.base import END_MOVE, MOVES, START_MOVE
from rlgp_exec.planning.actions.drawer import (
    CLOSE_DRAWER,
    DRAWER_ACTIONS,
    DRIVES,
    OPEN_DRAWER,
    TAKE_KNOB,
    opening_after,
)
from rlgp_exec.planning.actions.drop import DROP
from rlgp_exec.planning.actions.kind import ActionKind, Kind, action_text, describe, named_arm
from rlgp_exec.planning.actions.pick import PICK, PICK_FROM_DRAWER, PICKS
from rlgp_exec.planning.actions.place import PLACE, target_surface
from rlgp_exec.planning.actions.stack import STACK

__all__ = [
    "ACTION_KINDS",
    "DRAWER_ACTIONS",
    "DRIVES",
    "GEOMETRIC_ACTIONS",
    "GNPP_ACTIONS",
    "MOVES",
    "MOVES_OBJECT",
    "PICKS",
    "PUT_DOWN",
    "RELEASES",
    "SETS_DOWN",
    "ActionKind",
    "ActionWords",
    "Kind",
    "action_text",
    "describe",
    "ground_text",
    "kind",
    "named_arm",
    "opening_after",
    "parse_text",
    "target_surface",
]

#: every kind, R-LGP's geometric ones first in their domain order
ACTION_KINDS: tuple[ActionKind, ...] = (
    PICK, PLACE, STACK, DROP, TAKE_KNOB, OPEN_DRAWER, CLOSE_DRAWER, PICK_FROM_DRAWER, START_MOVE, END_MOVE,
)
#: the kinds R-LGP's geometric layers realise
GEOMETRIC_ACTIONS = tuple(k.name for k in ACTION_KINDS if k.rlgp)
MOVES_OBJECT = frozenset(k.name for k in ACTION_KINDS if k.moves_object)
RELEASES = frozenset(k.name for k in ACTION_KINDS if k.releases)
SETS_DOWN = frozenset(k.name for k in ACTION_KINDS if k.sets_down)
#: the kinds GNPP's graph-NLP realises
GNPP_ACTIONS = tuple(k.name for k in ACTION_KINDS if k.gnpp)
#: the kinds that let the held object go onto or into a target
PUT_DOWN = (Kind.PLACE, Kind.STACK, Kind.DROP)


def kind(name: str) -> ActionKind:
    """The kind called ``name``; RlgpError naming the valid kinds otherwise."""
    for k in ACTION_KINDS:
        if k.name == name:
            return k
    raise RlgpError(f"unknown action kind {name!r}; valid: {[k.name for k in ACTION_KINDS]}")


def ground_text(name: str, args: tuple[str, ...], name_arm: bool) -> str:
    """A ground action (the PDDL domain's ``name`` and ``args``) as ``Plan.actions`` writes it: the arm
    named only when ``name_arm`` (the robot has more than one)."""
    return describe(kind(name), args, name_arm)


class ActionWords(NamedTuple):
    """An action as ``Plan.actions`` wrote it, read back."""

    name: Kind
    arm: str | None  # None: not named (the robot has one)
    obj: str | None  # None for a base move
    target: str | None


def parse_text(text: str) -> ActionWords:
    """``"(place right_arm block tray)"`` -> ActionWords(PLACE, "right_arm", "block", "tray"): the kind's
    arguments say whether an arm was named. RlgpError naming the text if it is not an action."""
    words = text.strip().removeprefix("(").removesuffix(")").split()
    k = kind(words[0]) if words else None
    if k is None:
        raise RlgpError(f"{text!r} is not an action like '(pick block)'")
    rest = words[1:]
    n = int(k.has_object) + int(k.target != "none")
    if len(rest) not in (n, n + 1):
        raise RlgpError(f"{text!r}: {k.name} takes {n} words (an arm's name before them if the robot has two)")
    arm = rest.pop(0) if len(rest) == n + 1 else None
    obj = rest.pop(0) if k.has_object else None
    return ActionWords(k.name, arm, obj, rest[0] if rest else None)
