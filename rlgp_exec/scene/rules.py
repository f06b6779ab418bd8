"""The bounds a scene file must keep, each a constant with its reason, and the bounded quoting of bad
values in error messages. The loader and the geometric checks read them from here only."""

from __future__ import annotations

import itertools
import math
from typing import Any

__all__ = [
    "ANGLE_MAX",
    "COORD_MAX",
    "FILE_BYTES_MAX",
    "FIXTURE_SIZE_MAX",
    "HEIGHT_MAX",
    "ITEMS_MAX",
    "JOINT_TOLERANCE",
    "LITERALS_MAX",
    "MESSAGE_MAX",
    "NAME_MAX",
    "NESTING_MAX",
    "OBJECT_SIZE_MAX",
    "QUOTE_MAX",
    "SIZE_MIN",
    "START_OVERLAP",
    "WORKSPACE_RADIUS",
    "quote",
]

#: [m] smallest extent of an object, fixture, region, tag or drawer: below it grasps and the collision
#: checks' centimetre margins mean nothing
SIZE_MIN = 0.005
#: [m] largest extent of a movable object: neither robot's hand closes on or carries more
OBJECT_SIZE_MAX = 1.0
#: [m] largest extent of a fixture: one room; more is a unit slip (mm written as m)
FIXTURE_SIZE_MAX = 10.0
#: [m] every fixture and object centre lies this close to the robot's start (horizontally): base paths,
#: reachability graphs and collision worlds are sized for one room or lab
WORKSPACE_RADIUS = 30.0
#: [m] bound on every x, y coordinate: the planar base joints' position limits in RobotModel
COORD_MAX = 1000.0
#: [m] highest top of a fixture or object: far above either robot's reach (PR2, torso up: ~1.6 m)
HEIGHT_MAX = 3.0
#: [rad] bound on every yaw and continuous joint: more than a turn either way is a typo, and wrapping a
#: huge angle loses its precision
ANGLE_MAX = 2.0 * math.pi
#: [rad or m] a joint value may pass its URDF limit by this much: rounding in files written from joint states
JOINT_TOLERANCE = 1e-3
#: [m] how far the robot may reach into a fixture at the start (its base footprint, or a link at the start
#: configuration): the planners' collision tolerance, so a start deeper in has no collision-free first motion
START_OVERLAP = 1e-3
#: characters in a name: names appear in every plan, log and message
NAME_MAX = 64
#: fixtures, objects or regions in one scene: the task search is exponential in them, and the geometric
#: checks quadratic
ITEMS_MAX = 64
#: literals in the goal: each is one subgoal of the task search
LITERALS_MAX = 64
#: bytes in a scene file (shipped ones are ~3 kB): what cannot be a scene is not parsed
FILE_BYTES_MAX = 1 << 20
#: levels of tables and arrays (the deepest the contract has is 5: top, [[object]], item, random, x)
NESTING_MAX = 8
#: characters of a bad value quoted in a message
QUOTE_MAX = 60
#: characters of a whole error message, file and key path included: with a CLI's prefix still under 500
MESSAGE_MAX = 460

_ITEMS_QUOTED = 4
_DEPTH_QUOTED = 2


def _brief(value: Any, depth: int) -> str:
    if isinstance(value, str):
        return repr(value[: QUOTE_MAX + 1])
    if isinstance(value, bool) or value is None or isinstance(value, float):
        return repr(value)
    if isinstance(value, int):
        if value.bit_length() > 64:  # repr of a huge int is slow and refused above 4300 digits
            return f"<{'-' if value < 0 else ''}integer of ~{int(value.bit_length() * 0.30103) + 1} digits>"
        return repr(value)
    if isinstance(value, list | tuple | dict):
        open_, close = ("{", "}") if isinstance(value, dict) else ("[", "]")
        if depth >= _DEPTH_QUOTED:
            return f"{open_}...{close}" if value else f"{open_}{close}"
        if isinstance(value, dict):
            parts = [f"{_brief(k, depth + 1)}: {_brief(v, depth + 1)}"
                     for k, v in itertools.islice(value.items(), _ITEMS_QUOTED)]
        else:
            parts = [_brief(v, depth + 1) for v in itertools.islice(value, _ITEMS_QUOTED)]
        if len(value) > _ITEMS_QUOTED:
            parts.append(f"... ({len(value)} items)")
        return open_ + ", ".join(parts) + close
    return f"<{type(value).__name__}>"


def quote(value: Any) -> str:
    """``repr`` of a bad value for a message, at most about QUOTE_MAX characters whatever its size or depth."""
    text = _brief(value, 0)
    if len(text) > QUOTE_MAX:
        total = f" ({len(value)} characters)" if isinstance(value, str) else ""
        text = text[: QUOTE_MAX - 3] + "..." + total
    return text
