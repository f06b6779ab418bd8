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

SIZE_MIN = 0.005  # [m] least extent of an object, fixture, region, tag, drawer: below the checks' margins
OBJECT_SIZE_MAX = 1.0  # [m] most extent of a movable object: neither robot's hand closes on or carries more
FIXTURE_SIZE_MAX = 10.0  # [m] most extent of a fixture: one room; more is a unit slip (mm written as m)
WORKSPACE_RADIUS = 30.0  # [m] fixtures and objects from the robot's base: graphs and worlds span one room
COORD_MAX = 1000.0  # [m] bound on every x, y: the planar base joints' position limits in RobotModel
HEIGHT_MAX = 3.0  # [m] highest top of a fixture or object: far above either robot's reach (PR2: ~1.6 m)
ANGLE_MAX = 2.0 * math.pi  # [rad] bound on yaws and continuous joints: past a turn is a typo (or unit slip)
JOINT_TOLERANCE = 1e-3  # [rad or m] past a URDF limit: rounding in files written from joint states
START_OVERLAP = 1e-3  # [m] the robot's depth into a fixture at the start: the planners' collision tolerance
NAME_MAX = 64  # characters in a name: names appear in every plan, log and message
ITEMS_MAX = 64  # fixtures, objects or regions: the task search is exponential in them
LITERALS_MAX = 64  # goal literals: each is a subgoal of the task search
FILE_BYTES_MAX = 1 << 20  # bytes in a scene file (shipped ones: ~3 kB): what cannot be a scene is not parsed
NESTING_MAX = 8  # levels of tables and arrays: the contract's deepest is 5 (top, [[object]], item, random, x)
QUOTE_MAX = 60  # characters of a bad value quoted in a message
MESSAGE_MAX = 460  # characters of a whole error message: with a CLI's prefix still under 500

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
