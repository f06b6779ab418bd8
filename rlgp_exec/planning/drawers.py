"""Drawer cabinets as the planners see them: the knob's pose and the drawer's boxes at an opening, the
part of the drawer's interior a held object can be dropped into, and the ``in``/``open``/``closed``
literals evaluated on a state (object poses and drawer openings).

Frames: ``T_world_*`` (4, 4) homogeneous transforms; the opening d [m] is the prismatic joint's
value (0 = closed, ``travel`` = fully open), along the cabinet's local +x (``axis_world``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import PANEL, Box, CabinetGeometry, cabinet_geometry

__all__ = [
    "CLOSED_TOLERANCE",
    "DROP_CLEARANCE",
    "IN_TOLERANCE",
    "DrawerView",
    "drawer_view",
    "drawer_views",
]

CLOSED_TOLERANCE = 0.005  # [m] a drawer is closed when out by at most this
IN_TOLERANCE = 0.01  # [m] an object is in a drawer when its bottom is within this of the drawer's floor
DROP_CLEARANCE = 0.03  # [m] a dropped object keeps this far from the carcass front and the drawer's walls


@dataclass(frozen=True)
class DrawerView:
    """One drawer cabinet's geometry with the opening as a parameter."""

    name: str
    geometry: CabinetGeometry

    @property
    def travel(self) -> float:
        return self.geometry.travel

    @property
    def axis_world(self) -> FloatArray:
        """(3,) the unit direction the drawer opens along."""
        return np.asarray(self.geometry.axis_world, float)

    def T_world_drawer(self, opening: float) -> FloatArray:
        return self.geometry.T_world_drawer(opening)

    def T_world_knob(self, opening: float) -> FloatArray:
        """The knob's centre (4, 4); its x axis is the opening direction."""
        return self.T_world_drawer(opening) @ self.geometry.T_drawer_knob

    def boxes(self, opening: float, knob: bool = True) -> list[Box]:
        """The drawer's boxes (bottom, front, back, sides, and the knob unless ``knob`` is False) in the
        world frame at ``opening``."""
        T = self.T_world_drawer(opening)
        return [
            Box(b.name, b.size, T @ b.T, b.color)
            for b in self.geometry.drawer
            if knob or not b.name.endswith(".knob")
        ]

    def floor_z(self, opening: float = 0.0) -> float:
        """Height [m] of the drawer's inner floor (the top of its bottom panel)."""
        inner = self.geometry.inner_box
        return float((self.T_world_drawer(opening) @ inner.T)[2, 3] - inner.size[2] / 2)

    def rim_z(self, opening: float = 0.0) -> float:
        """Height [m] of the drawer walls' top edge."""
        inner = self.geometry.inner_box
        return float((self.T_world_drawer(opening) @ inner.T)[2, 3] + inner.size[2] / 2)

    def drop_rect(self, opening: float, half_footprint: float) -> tuple[FloatArray, tuple[float, float]]:
        """Where an object of footprint half-size ``half_footprint`` [m] can be dropped: the part of the
        interior pulled out of the carcass, shrunk by the object and DROP_CLEARANCE; as (T (4, 4) of the
        rectangle's centre on the floor, half extents). Raises RlgpError if the opening leaves no room."""
        inner = self.geometry.inner_box
        dd = inner.size[0] + 2 * PANEL  # outer depth of the drawer
        m = half_footprint + DROP_CLEARANCE
        x_lo = max(dd / 2 - opening + m, -inner.size[0] / 2 + m)  # behind the carcass front: no access
        x_hi = inner.size[0] / 2 - m
        y_half = inner.size[1] / 2 - m
        if x_hi <= x_lo or y_half <= 0:
            raise RlgpError(
                f"drawer of {self.name!r} open by {opening:.3f} m leaves no room to drop an object of "
                f"footprint {2 * half_footprint:.3f} m"
            )
        T = self.T_world_drawer(opening) @ inner.T
        T = T @ _translation(((x_lo + x_hi) / 2, 0.0, -inner.size[2] / 2))
        return T, ((x_hi - x_lo) / 2, y_half)

    def holds(self, T_world_obj: FloatArray, size: tuple[float, float, float], opening: float) -> tuple[bool, str]:
        """Is an object (centre pose, full extents) in the drawer: its centre over the interior and its
        lowest point on the floor (within IN_TOLERANCE), upright or not?"""
        inner = self.geometry.inner_box
        T_in = self.T_world_drawer(opening) @ inner.T
        local = np.linalg.solve(T_in, T_world_obj[:, 3])
        # the lowest point of the object's box, whatever its attitude (a dropped block may lie on its side)
        half_z = float(np.abs(T_world_obj[2, :3]) @ (np.asarray(size, float) / 2))
        bottom = float(T_world_obj[2, 3] - half_z) - self.floor_z(opening)
        ok = (
            abs(local[0]) <= inner.size[0] / 2
            and abs(local[1]) <= inner.size[1] / 2
            and abs(bottom) <= IN_TOLERANCE
        )
        return ok, f"centre ({local[0]:+.3f}, {local[1]:+.3f}) m in the drawer, bottom {bottom:+.3f} m from its floor"

    def contains_point(self, p_world: FloatArray, opening: float) -> bool:
        """Is a world point inside the drawer's interior volume (walls' height, up to the rim)?"""
        inner = self.geometry.inner_box
        local = np.linalg.solve(self.T_world_drawer(opening) @ inner.T, np.r_[np.asarray(p_world, float)[:3], 1.0])
        return bool(np.all(np.abs(local[:3]) <= np.asarray(inner.size) / 2 + 1e-6))


def _translation(xyz: tuple[float, float, float]) -> FloatArray:
    T = np.eye(4)
    T[:3, 3] = xyz
    return T


def drawer_views(scene: Scene) -> dict[str, DrawerView]:
    """Every drawer cabinet of the scene, by name."""
    return {
        fx.name: DrawerView(fx.name, cabinet_geometry(fx)) for fx in scene.fixtures if fx.kind == "drawer_cabinet"
    }


def drawer_view(scene: Scene, name: str) -> DrawerView:
    views = drawer_views(scene)
    if name not in views:
        raise RlgpError(f"{name!r} is not a drawer cabinet; valid: {sorted(views)}")
    return views[name]
