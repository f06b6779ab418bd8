"""Recoveries the executive runs before it can plan again: a stop with the hand on a drawer's knob.

The planners start from a free hand (an object in it is fine, a knob is not): stopped while driving a
drawer (a cancel, an e-stop, a monitor), the hand still closes round the knob with the drawer part
way out. Letting go is what every plan's open/close phase does at its end: open the hand where it
is, then back the base off ``LEAVE_M`` along the drawer's opening axis (out of the cabinet), the
fingers allowed round the knob. The two phases are checked by the same PyBullet replay as any plan,
in the sensed world (the drawer at its sensed opening), before anything moves.
"""

from __future__ import annotations

import numpy as np

from rlgp_exec.planning.drawers import drawer_view
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.sequence import APPROACH
from rlgp_exec.planning.validate import Phase, validate_plan
from rlgp_exec.reach.build import nominal_q
from rlgp_exec.robot.model import RobotModel
from rlgp_exec.scene import Scene

__all__ = ["LEAVE_M", "release_knob"]

LEAVE_M = APPROACH  # [m] the base backs off this far along the drawer's axis, as the plans' leave phase


def release_knob(model: RobotModel, scene: Scene, cabinet: str) -> Plan:
    """Let go of ``cabinet``'s knob from the robot's configuration in ``scene`` (the sensed world model,
    the drawer at its sensed opening) and back off along the drawer's axis, as a plan whose ``success``
    says the motion replays collision-free (``reason``: the collisions otherwise)."""
    q = nominal_q(model, scene)
    q_leave = q.copy()
    q_leave[:2] += LEAVE_M * drawer_view(scene, cabinet).axis_world[:2]
    phases = (
        Phase(q[None], None, knob=cabinet, drives_drawer=True),  # ends with the hand opening
        Phase(np.array([q, q_leave]), None, knob=cabinet),
    )
    validation = validate_plan(scene, phases)
    reason = "ok" if validation.collision_free else "; ".join(validation.collisions[:3])
    actions = (f"(release_knob {cabinet})",)
    return Plan(validation.collision_free, "recovery", actions, q[None], phases, 0.0, 0, 0, validation, reason)
