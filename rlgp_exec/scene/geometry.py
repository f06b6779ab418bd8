"""Scene geometry as boxes: fixtures, drawer cabinets, objects, regions, support surfaces.

Both the PyBullet builder (``rlgp_exec/world/pybullet_world.py``) and the planners' collision model build from these
boxes, so simulation and planning agree. All boxes rotate about z only (yaw), which keeps the
overlap test exact (separating axes in the plane + a z-interval test).

Drawer cabinet (``kind = "drawer_cabinet"``), in the cabinet frame (origin at the centre of its
``size`` box, yaw of its pose): a carcass of 2 cm panels (top, bottom, two sides, back, and front
panels above and below the drawer slot) open on the local +x face; a drawer that is an open-top
box (bottom, front, back, two sides) of outer depth ``sx - 5 cm``, width ``sy - 5 cm`` and height
``drawer.height``, its front flush with the carcass when closed and centred on ``knob_height``
(above the floor), sliding along +x by ``0 <= d <= travel``; a knob (3 x 8 x 3 cm) on its front.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from rlgp_exec.scene.types import COLORS, Fixture, Region, Scene, SceneObject, pose_matrix

__all__ = [
    "PANEL",
    "Box",
    "CabinetGeometry",
    "Surface",
    "boxes_overlap",
    "cabinet_geometry",
    "fixture_boxes",
    "object_box",
    "region_box",
    "support_surfaces",
]

FloatArray = NDArray[np.float64]
PANEL = 0.02  # [m] cabinet panel thickness
KNOB_SIZE = (0.03, 0.08, 0.03)


@dataclass(frozen=True)
class Box:
    """An oriented box: full extents ``size`` (3,) [m], pose ``T`` (4, 4) of its centre."""

    name: str
    size: tuple[float, float, float]
    T: FloatArray
    color: tuple[float, float, float, float]

    @property
    def yaw(self) -> float:
        return float(np.arctan2(self.T[1, 0], self.T[0, 0]))


@dataclass(frozen=True)
class CabinetGeometry:
    T_world_cabinet: FloatArray  # (4, 4), the carcass frame
    carcass: tuple[Box, ...]  # world frame
    drawer: tuple[Box, ...]  # drawer frame (the knob included, last)
    T_world_drawer_closed: FloatArray  # (4, 4)
    axis_world: FloatArray  # (3,), the drawer's opening direction
    travel: float  # [m]
    T_drawer_knob: FloatArray  # (4, 4), knob centre in the drawer frame
    inner_box: Box  # usable volume inside the drawer, drawer frame

    def T_world_drawer(self, opening: float) -> FloatArray:
        T = self.T_world_drawer_closed.copy()
        T[:3, 3] += opening * self.axis_world
        return T


@dataclass(frozen=True)
class Surface:
    """A horizontal support surface: a rectangle of ``size`` (2,) centred at ``T`` (4, 4), facing up."""

    name: str
    T: FloatArray
    size: tuple[float, float]

    @property
    def z(self) -> float:
        return float(self.T[2, 3])

    def contains(self, xy: FloatArray, margin: float = 0.0) -> bool:
        """Is world point ``xy`` (2,) on the surface, at least ``margin`` [m] from its edges?"""
        local = self.T[:2, :2].T @ (np.asarray(xy, float) - self.T[:2, 3])
        return bool(np.all(np.abs(local) <= np.asarray(self.size) / 2 - margin + 1e-9))


def _local(T_parent: FloatArray, xyz: tuple[float, float, float]) -> FloatArray:
    T = np.eye(4)
    T[:3, 3] = xyz
    return T_parent @ T


def fixture_boxes(fx: Fixture) -> tuple[Box, ...]:
    """The boxes of a static fixture (cylinders are boxed by their square footprint)."""
    if fx.kind == "drawer_cabinet":
        return cabinet_geometry(fx).carcass
    return (Box(fx.name, fx.size, fx.T, COLORS[fx.color]),)


def cabinet_geometry(fx: Fixture) -> CabinetGeometry:
    if fx.drawer is None:
        raise ValueError(f"fixture {fx.name!r} has no drawer")
    sx, sy, sz = fx.size
    t = PANEL
    Tc = fx.T
    col = COLORS[fx.color]
    dd, dw, hd = sx - 2.5 * t, sy - 2.5 * t, fx.drawer.height
    zc = fx.drawer.knob_height - fx.pose[2]  # drawer centre height in the cabinet frame
    slot_lo, slot_hi = zc - hd / 2 - 0.005, zc + hd / 2 + 0.005
    inner_lo, inner_hi = -sz / 2 + t, sz / 2 - t
    carcass = [
        Box(f"{fx.name}.top", (sx, sy, t), _local(Tc, (0, 0, sz / 2 - t / 2)), col),
        Box(f"{fx.name}.bottom", (sx, sy, t), _local(Tc, (0, 0, -sz / 2 + t / 2)), col),
        Box(f"{fx.name}.side_l", (sx, t, sz - 2 * t), _local(Tc, (0, sy / 2 - t / 2, 0)), col),
        Box(f"{fx.name}.side_r", (sx, t, sz - 2 * t), _local(Tc, (0, -sy / 2 + t / 2, 0)), col),
        Box(f"{fx.name}.back", (t, sy - 2 * t, sz - 2 * t), _local(Tc, (-sx / 2 + t / 2, 0, 0)), col),
    ]
    if slot_lo - inner_lo > 1e-6:
        h = slot_lo - inner_lo
        carcass.append(Box(f"{fx.name}.front_low", (t, sy - 2 * t, h),
                           _local(Tc, (sx / 2 - t / 2, 0, inner_lo + h / 2)), col))
    if inner_hi - slot_hi > 1e-6:
        h = inner_hi - slot_hi
        carcass.append(Box(f"{fx.name}.front_high", (t, sy - 2 * t, h),
                           _local(Tc, (sx / 2 - t / 2, 0, slot_hi + h / 2)), col))
    T_drawer = _local(Tc, (sx / 2 - dd / 2, 0.0, zc))
    dcol = COLORS["wood"]
    eye = np.eye(4)
    drawer = [
        Box(f"{fx.name}.drawer.bottom", (dd - 2 * t, dw - 2 * t, t), _local(eye, (0, 0, -hd / 2 + t / 2)), dcol),
        Box(f"{fx.name}.drawer.front", (t, dw, hd), _local(eye, (dd / 2 - t / 2, 0, 0)), dcol),
        Box(f"{fx.name}.drawer.back", (t, dw, hd), _local(eye, (-dd / 2 + t / 2, 0, 0)), dcol),
        Box(f"{fx.name}.drawer.side_l", (dd - 2 * t, t, hd), _local(eye, (0, dw / 2 - t / 2, 0)), dcol),
        Box(f"{fx.name}.drawer.side_r", (dd - 2 * t, t, hd), _local(eye, (0, -dw / 2 + t / 2, 0)), dcol),
    ]
    T_knob = _local(eye, (dd / 2 + KNOB_SIZE[0] / 2, 0.0, 0.0))
    drawer.append(Box(f"{fx.name}.knob", KNOB_SIZE, T_knob, COLORS["black"]))
    inner = Box(f"{fx.name}.drawer.inner", (dd - 2 * t, dw - 2 * t, hd - t), _local(eye, (0, 0, t / 2)), dcol)
    return CabinetGeometry(
        T_world_cabinet=Tc, carcass=tuple(carcass), drawer=tuple(drawer), T_world_drawer_closed=T_drawer,
        axis_world=Tc[:3, 0].copy(), travel=fx.drawer.travel, T_drawer_knob=T_knob, inner_box=inner,
    )


def object_box(obj: SceneObject) -> Box:
    return Box(obj.name, obj.size, obj.T, COLORS[obj.color])


def region_box(scene: Scene, region: Region, thickness: float = 0.002) -> Box:
    """The region as a thin box lying on its fixture's top face."""
    fx = scene.fixture(region.on)
    T = _local(fx.T, (region.offset[0], region.offset[1], fx.size[2] / 2 + thickness / 2 + 0.0005))
    return Box(region.name, (region.size[0], region.size[1], thickness), T, COLORS[region.color])


def support_surfaces(
    scene: Scene, exclude: str | None = None, openings: Mapping[str, float] | None = None
) -> list[Surface]:
    """Every surface an object may rest on: fixture tops, cabinet tops, drawer bottoms (pulled out by
    ``openings`` [m], cabinet name -> opening; None: as ``scene.start`` has them), the tops of the
    objects not in the hand."""
    out: list[Surface] = []
    openings = dict(scene.start.openings) if openings is None else openings
    for fx in scene.fixtures:
        if fx.kind == "drawer_cabinet":
            g = cabinet_geometry(fx)
            top = g.carcass[0]
            out.append(Surface(fx.name, _local(top.T, (0, 0, top.size[2] / 2)), top.size[:2]))
            inner = g.inner_box
            T_in = g.T_world_drawer_closed @ inner.T
            T_in[:3, 3] += openings.get(fx.name, 0.0) * np.asarray(g.axis_world, float)
            out.append(Surface(f"{fx.name}.drawer", _local(T_in, (0, 0, -inner.size[2] / 2)), inner.size[:2]))
        else:
            out.append(Surface(fx.name, _local(fx.T, (0, 0, fx.size[2] / 2)), fx.size[:2]))
    for o in scene.objects:
        if o.name != exclude and o.name != scene.start.held:
            out.append(Surface(o.name, _local(o.T, (0, 0, o.size[2] / 2)), o.size[:2]))
    return out


def _corners_2d(b: Box) -> FloatArray:
    hx, hy = b.size[0] / 2, b.size[1] / 2
    local = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]])
    return local @ b.T[:2, :2].T + b.T[:2, 3]


def boxes_overlap(a: Box, b: Box, tolerance: float = 1e-3) -> bool:
    """Do two yaw-only boxes interpenetrate by more than ``tolerance`` [m] (touching is allowed)?"""
    za, zb = a.T[2, 3], b.T[2, 3]
    if (a.size[2] + b.size[2]) / 2 - abs(za - zb) <= tolerance:
        return False
    ca, cb = _corners_2d(a), _corners_2d(b)
    for box in (a, b):
        for axis in (box.T[:2, 0], box.T[:2, 1]):
            pa, pb = ca @ axis, cb @ axis
            if min(pa.max(), pb.max()) - max(pa.min(), pb.min()) <= tolerance:
                return False
    return True


def pose_of(T: FloatArray) -> tuple[float, float, float, float]:
    """[x, y, z, yaw] of a yaw-only T (4, 4)."""
    return (float(T[0, 3]), float(T[1, 3]), float(T[2, 3]), float(np.arctan2(T[1, 0], T[0, 0])))


__all__ += ["pose_matrix", "pose_of"]

TAG_LIFT = 0.002  # [m] a tag quad floats this far above its object's top face (no z-fighting in renders)


def T_object_tag(obj: SceneObject) -> FloatArray:
    """T_object_tag (4, 4): a tag sits centred on the object's top face, its axes along the object's."""
    T = np.eye(4)
    T[2, 3] = obj.size[2] / 2.0 + TAG_LIFT
    return T


__all__ += ["TAG_LIFT", "T_object_tag"]
