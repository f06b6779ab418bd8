"""Object poses along a solved action sequence (numerically, from the keyframes): what each action
leaves behind. A picked object rides with the hand; a placed one stays where the hand released it; a
dropped one falls straight down onto the drawer's floor (it was released upright over the interior);
objects in a drawer move with it when it opens or closes.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from rlgp_exec.planning.actions import RELEASES, Kind
from rlgp_exec.planning.drawers import DrawerView
from rlgp_exec.robot.model import FloatArray, RobotModel

if TYPE_CHECKING:
    from rlgp_exec.planning.nlp.action import Action

__all__ = ["object_poses_after"]


def object_poses_after(
    actions: Sequence[Action],
    keyframes: FloatArray,
    start: dict[str, FloatArray],
    openings: Sequence[dict[str, float]],
    drawers: dict[str, DrawerView],
    model: RobotModel,
    tool: str,
    sizes: dict[str, tuple[float, float, float]] | None = None,
    held_T: FloatArray | None = None,
    openings0: dict[str, float] | None = None,
) -> list[dict[str, FloatArray]]:
    """T_world_obj of every object after each action. ``openings[k]``: the drawers' openings at keyframe
    k (after an open/close, the new opening); ``sizes``: full extents of the objects (for drops);
    ``held_T``: T_tool_obj of an object in the hand at the start; ``openings0``: the drawers' openings
    at the start [m] (closed if absent)."""
    out: list[dict[str, FloatArray]] = []
    cur = {k: v.copy() for k, v in start.items()}
    before = {c: (openings0 or {}).get(c, 0.0) for c in drawers}
    for k, a in enumerate(actions):
        T_tool = model.fk(keyframes[k], tool)
        if a.name == Kind.PICK:
            held_T = np.linalg.inv(T_tool) @ cur[a.obj]
        elif a.name in RELEASES and held_T is not None:
            cur[a.obj] = T_tool @ held_T
            if a.name == Kind.DROP and a.target is not None and sizes is not None:
                v = drawers[a.target]
                cur[a.obj][2, 3] = v.floor_z(openings[k][a.target]) + sizes[a.obj][2] / 2
            held_T = None
        elif a.name in (Kind.OPEN_DRAWER, Kind.CLOSE_DRAWER):
            v = drawers[a.obj]
            d0, d1 = before[a.obj], openings[k][a.obj]
            for name, T in cur.items():
                if v.contains_point(T[:3, 3], d0):
                    cur[name] = T.copy()
                    cur[name][:3, 3] += (d1 - d0) * v.axis_world
        before = dict(openings[k])
        out.append({n: T.copy() for n, T in cur.items()})
    return out
