"""What a head camera cannot see of the drawers, kept by proprioception: how far each drawer is out, and
where the objects put into one are.

A camera sees neither a drawer's travel (no tag on it) nor into a closed drawer. The hand knows both:

* when the gripper closes with the tool frame at a drawer's knob, the drawer rides with the tool along
  its axis (clamped to its travel) until the gripper opens; the objects inside it ride along;
* an object let go above an open drawer's inside comes to rest on its floor (a drop falls);
* an object inside a cabinet (in its drawer or behind its front) is hidden from the camera: not being
  seen is no evidence it is gone, and its estimate does not age out.

Openings start from the scene's start state (a scene file's drawers are closed).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np

from rlgp_exec.executive.world import DRAWER_SUFFIX
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import CabinetGeometry, cabinet_geometry

__all__ = ["KNOB_TOUCH_M", "DrawerMemory", "KnobGrasp"]

log = logging.getLogger(__name__)

KNOB_TOUCH_M = 0.06  # [m] the tool frame this close to a knob when the gripper closes: the knob is held
INSIDE_MARGIN_M = 0.02  # [m] around a drawer's inside and a cabinet's carcass: an object there is hidden


@dataclass(frozen=True)
class KnobGrasp:
    cabinet: str
    opening0: float  # [m] the drawer's opening when the knob was taken
    p_tool0: FloatArray  # (3,) the tool frame's position then, world
    contents: tuple[str, ...]  # objects inside the drawer then (they ride with it)


def _inside(T_frame_box: FloatArray, size: tuple[float, float, float], p_frame: FloatArray, margin: float) -> bool:
    p = np.linalg.inv(T_frame_box) @ np.append(p_frame, 1.0)
    return bool(np.all(np.abs(p[:3]) <= np.asarray(size) / 2 + margin))


class DrawerMemory:
    """Drawer openings and drawer contents of one scene's cabinets (not thread-safe: the caller locks)."""

    def __init__(self, scene: Scene) -> None:
        self.cabinets: dict[str, CabinetGeometry] = {
            fx.name: cabinet_geometry(fx) for fx in scene.fixtures if fx.kind == "drawer_cabinet"
        }
        self._carcass = {fx.name: (fx.T, fx.size) for fx in scene.fixtures if fx.kind == "drawer_cabinet"}
        self.openings: dict[str, float] = {c: scene.start.opening(c) for c in self.cabinets}
        self._heights = {o.name: float(o.size[2]) for o in scene.objects}
        self.knob: KnobGrasp | None = None

    # ------------------------------------------------------------------ geometry
    def T_world_drawer(self, cabinet: str, opening: float | None = None) -> FloatArray:
        o = self.openings[cabinet] if opening is None else opening
        return self.cabinets[cabinet].T_world_drawer(o)

    def knob_position(self, cabinet: str) -> FloatArray:
        g = self.cabinets[cabinet]
        return (self.T_world_drawer(cabinet) @ g.T_drawer_knob)[:3, 3]

    def in_drawer(self, cabinet: str, p_world: FloatArray, margin: float = INSIDE_MARGIN_M) -> bool:
        """Whether ``p_world`` (3,) is inside the drawer's usable volume at its current opening."""
        g = self.cabinets[cabinet]
        return _inside(self.T_world_drawer(cabinet) @ g.inner_box.T, g.inner_box.size, p_world, margin)

    def hidden(self, p_world: FloatArray) -> bool:
        """Whether an object at ``p_world`` is inside a drawer or a cabinet's carcass: out of the camera's sight."""
        for c, (T, size) in self._carcass.items():
            if self.in_drawer(c, p_world) or _inside(T, size, p_world, INSIDE_MARGIN_M):
                return True
        return False

    # ------------------------------------------------------------------ the hand
    def nearest_knob(self, p_tool: FloatArray) -> tuple[float, str] | None:
        """(distance [m], cabinet) of the knob nearest the tool, if within KNOB_TOUCH_M."""
        near = [(float(np.linalg.norm(self.knob_position(c) - p_tool)), c) for c in self.cabinets]
        near = [x for x in near if x[0] < KNOB_TOUCH_M]
        return min(near) if near else None

    def take_knob(self, cabinet: str, p_tool: FloatArray, estimates: dict[str, FloatArray]) -> None:
        contents = tuple(sorted(n for n, T in estimates.items() if self.in_drawer(cabinet, T[:3, 3])))
        self.knob = KnobGrasp(cabinet, self.openings[cabinet], np.asarray(p_tool, float).copy(), contents)
        log.info("camera: the knob of %s taken (drawer out %.3f m, holding %s)", cabinet,
                 self.openings[cabinet], list(contents) or "nothing")

    def opening_now(self, p_tool: FloatArray) -> float | None:
        """The held drawer's opening [m] with the tool at ``p_tool`` (3,); None when no knob is held."""
        k = self.knob
        if k is None:
            return None
        g = self.cabinets[k.cabinet]
        d = float(np.dot(np.asarray(p_tool) - k.p_tool0, g.axis_world))
        return float(np.clip(k.opening0 + d, 0.0, g.travel))

    def shift(self, opening: float) -> FloatArray | None:
        """(3,) how far [m] the held drawer's contents moved since the knob was taken, at ``opening``."""
        k = self.knob
        if k is None:
            return None
        return (opening - k.opening0) * self.cabinets[k.cabinet].axis_world

    def release_knob(self, p_tool: FloatArray) -> tuple[str, ...]:
        """Let go of the knob: the drawer stays where the tool left it; returns the contents that rode."""
        k = self.knob
        assert k is not None
        opening = self.opening_now(p_tool)
        assert opening is not None
        self.openings[k.cabinet] = opening
        self.knob = None
        log.info("camera: the knob of %s released (drawer out %.3f m)", k.cabinet, opening)
        return k.contents

    def settle(self, name: str, T_world_object: FloatArray) -> FloatArray:
        """Where an object let go at ``T_world_object`` rests: on the floor of an open drawer below it
        (upright, its centre half its height above the floor), else where it was let go."""
        p = T_world_object[:3, 3]
        for c, g in self.cabinets.items():
            T_inner = self.T_world_drawer(c) @ g.inner_box.T
            local = (np.linalg.inv(T_inner) @ np.append(p, 1.0))[:3]
            half = np.asarray(g.inner_box.size) / 2
            if np.all(np.abs(local[:2]) <= half[:2]) and local[2] > -half[2]:  # above the floor, inside its outline
                T = np.eye(4)
                yaw = float(np.arctan2(T_world_object[1, 0], T_world_object[0, 0]))
                T[:2, :2] = [[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]]
                floor = (T_inner @ np.array([local[0], local[1], -half[2], 1.0]))[:3]
                T[:3, 3] = floor + np.array([0.0, 0.0, self._heights.get(name, 0.0) / 2])
                log.info("camera: %s let go over the drawer of %s: on its floor", name, c)
                return T
        return T_world_object

    def frames(self, p_tool: FloatArray | None) -> dict[str, FloatArray]:
        """``<cabinet>.drawer`` -> T_world_drawer (4, 4) of every drawer, the held one at the tool's position."""
        out = {}
        for c in self.cabinets:
            o = self.openings[c]
            if self.knob is not None and self.knob.cabinet == c and p_tool is not None:
                o = self.opening_now(p_tool) or 0.0
            out[f"{c}{DRAWER_SUFFIX}"] = self.T_world_drawer(c, o)
        return out
