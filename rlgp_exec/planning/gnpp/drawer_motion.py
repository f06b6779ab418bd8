"""The drawer actions' motions in GNPP's layout (``motion.phases_of``), as R-LGP lays them out
(``sequence``): the hand comes onto a knob along the drawer's axis, from ``APPROACH`` out; an open or close
is one phase that drives the drawer (the base moves along the axis with the hand on the knob, the replay's
articulated check, ``drawer_replay``), then the hand lets go and backs off along the axis; a drop is a
release whose object falls into the drawer.

``DrawerState`` follows the drawers' openings and the objects in them through the plan, so that the
objects' poses (drawer frame in the graph-NLP) are obstacles where they are in the world.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from rlgp_exec.planning.actions import DRAWER_ACTIONS as CABINET_ACTIONS
from rlgp_exec.planning.actions import DRIVES, PICKS, Kind, opening_after
from rlgp_exec.planning.gnpp.pntc import Var
from rlgp_exec.planning.symbolic.model import GroundAction
from rlgp_exec.planning.transport import APPROACH
from rlgp_exec.robot.model import FloatArray

__all__ = ["APPROACH", "DRAWER_ACTIONS", "DRIVES", "DrawerState", "along_axis"]

#: the kinds GNPP's drawer factors handle: those with a cabinet argument
DRAWER_ACTIONS = (*CABINET_ACTIONS, Kind.DROP)


def along_axis(lib, cabinet: str, q: FloatArray, distance: float) -> FloatArray:
    """A mobile arm's variable q with its base moved ``distance`` [m] along the cabinet's opening axis
    (out of the cabinet if > 0)."""
    out = np.asarray(q, float).copy()
    out[:2] += distance * lib.drawers[cabinet].axis_world[:2]
    return out


@dataclass
class DrawerState:
    """The drawers' openings [m] and the objects in them (object -> cabinet) before the next action."""

    openings: dict[str, float]
    inside: dict[str, str] = field(default_factory=dict)

    @classmethod
    def start(cls, lib) -> DrawerState:
        inside = {n: o.support.removesuffix(".drawer") for n, o in lib.objects.items() if o.support.endswith(".drawer")}
        return cls(dict.fromkeys(lib.drawers, 0.0), inside)

    def world(self, lib, obj: str, values: Mapping[Var, FloatArray], t: int) -> FloatArray:
        """The world pose (4,) of a resting object at step t (its graph value, the start's if none)."""
        w = values.get(Var("x", obj, t), lib.start_pose(obj))
        c = self.inside.get(obj)
        return w if c is None else lib.in_world(c, self.openings[c], w)

    def after(self, lib, a: GroundAction) -> None:
        """The state after action ``a``."""
        if a.name in DRIVES:
            c = a.args[1]
            self.openings[c] = opening_after(a.name, lib.drawers[c].travel)
        elif a.name == Kind.DROP:
            self.inside[a.args[1]] = a.args[2]
        elif a.name in PICKS:
            self.inside.pop(a.args[1], None)
