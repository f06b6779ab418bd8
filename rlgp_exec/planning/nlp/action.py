"""A symbolic action as the geometric layers read it (the surface a place or stack targets is the place
kind's: ``planning.actions.target_surface``, re-exported here)."""

from __future__ import annotations

from dataclasses import dataclass

from rlgp_exec.planning.actions import action_text, target_surface

__all__ = ["Action", "target_surface"]


@dataclass(frozen=True)
class Action:
    name: str  # an action kind (``planning.actions.Kind``)
    obj: str  # the object; the cabinet for take_knob, open_drawer, close_drawer
    target: str | None = None  # place: a region or a fixture; stack: a region or a movable; drop: the cabinet

    def __str__(self) -> str:
        return action_text(self.name, self.obj, self.target)

    def text(self, arm: str | None) -> str:
        """As ``Plan.actions`` writes it: ``arm`` named (the robot has more than one), or not (None)."""
        return action_text(self.name, self.obj, self.target, arm)
