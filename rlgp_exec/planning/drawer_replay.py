"""The drawers in the replay: the drawer joint following the hand that holds its knob (with whatever lies
in the drawer), a dropped object falling, and the ``in``/``open``/``closed`` goal literals.

The articulated constraint is checked, not assumed: while the hand holds the knob, the knob can only
move along the drawer's axis, so the hand's displacement off that axis (more than ``OFF_AXIS`` [m])
or past the joint's range is a violation of the plan.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pybullet as p

from rlgp_exec.planning.drawers import CLOSED_TOLERANCE, DrawerView, drawer_views
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.types import Literal

__all__ = ["OFF_AXIS", "DrawerMotion", "drawer_literal_holds", "settle"]

OFF_AXIS = 0.005  # [m] the hand on a knob may leave the drawer's axis by at most this
FALL_STEP = 0.002  # [m] a falling object is lowered this far per check
MAX_FALL = 0.6  # [m]


@dataclass
class DrawerMotion:
    """A drawer driven by the hand: the opening follows the tool's displacement along the axis."""

    cabinet: str
    view: DrawerView
    opening0: float  # [m] at the start of the motion
    p0: FloatArray  # (3,) the tool's position at the start, world frame
    riders: dict[str, FloatArray]  # objects in the drawer: T_drawer_obj (4, 4)

    @classmethod
    def start(cls, world, cabinet: str, T_world_tool: FloatArray) -> DrawerMotion:
        view = drawer_views(world.scene)[cabinet]
        d0 = world.drawer_opening(cabinet)
        T_d = view.T_world_drawer(d0)
        riders = {
            name: np.linalg.solve(T_d, world.object_pose(name))
            for name in world.objects
            if view.contains_point(world.object_pose(name)[:3, 3], d0)
        }
        return cls(cabinet, view, d0, T_world_tool[:3, 3].copy(), riders)

    def follow(self, world, T_world_tool: FloatArray) -> str | None:
        """Move the drawer (and its contents) with the hand; a violation described, or None."""
        delta = T_world_tool[:3, 3] - self.p0
        along = float(delta @ self.view.axis_world)
        off = float(np.linalg.norm(delta - along * self.view.axis_world))
        d = self.opening0 + along
        if off > OFF_AXIS:
            return f"the hand on the knob of {self.cabinet} leaves the drawer's axis by {off * 1e3:.1f} mm"
        if not (-OFF_AXIS <= d <= self.view.travel + OFF_AXIS):
            return f"the hand pulls the drawer of {self.cabinet} to {d:.3f} m, outside [0, {self.view.travel}]"
        d = min(max(d, 0.0), self.view.travel)
        world.set_drawer_opening(self.cabinet, d)
        T_d = self.view.T_world_drawer(d)
        for name, T_rel in self.riders.items():
            world.set_object_pose(name, T_d @ T_rel)
        return None


def settle(world, name: str, robot_id: int, tolerance: float) -> float:
    """Let a released object fall straight down until it touches something (not the robot, whose hand
    has opened); returns the fall [m]."""
    body = world.objects[name]
    T = world.object_pose(name)
    fallen = 0.0
    while fallen < MAX_FALL:
        T_next = T.copy()
        T_next[2, 3] -= FALL_STEP
        world.set_object_pose(name, T_next)
        p.performCollisionDetection(physicsClientId=world.client)
        hit = any(
            c[2] != robot_id and c[8] < -tolerance for c in p.getContactPoints(bodyA=body, physicsClientId=world.client)
        )
        if hit:
            break
        T, fallen = T_next, fallen + FALL_STEP
    world.set_object_pose(name, T)
    return fallen


def drawer_literal_holds(
    scene: Scene, literal: Literal, poses: dict[str, FloatArray], openings: dict[str, float]
) -> tuple[bool, str]:
    """(holds, why) for ``(in o c)``, ``(open c)``, ``(closed c)``; a drawer not in ``openings`` is closed."""
    views = drawer_views(scene)
    c = literal.args[-1]
    if c not in views:
        return False, f"{literal}: {c!r} is not a drawer cabinet; valid: {sorted(views)}"
    d = float(openings.get(c, 0.0))
    if literal.predicate == "closed":
        return d <= CLOSED_TOLERANCE, f"{literal}: the drawer is out by {d:.3f} m"
    if literal.predicate == "open":
        return d >= views[c].travel - 0.01, f"{literal}: the drawer is out by {d:.3f} of {views[c].travel} m"
    obj = literal.args[0]
    if obj not in poses:
        return False, f"{literal}: unknown object {obj!r}; valid: {sorted(poses)}"
    ok, why = views[c].holds(poses[obj], scene.object(obj).size, d)
    return ok, f"{literal}: {why}"
