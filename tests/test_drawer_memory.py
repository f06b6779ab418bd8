"""Drawers by proprioception (rlgp_exec/executive/drawer_memory.py, used by the camera source): the opening
follows the hand on the knob, drops land on the drawer's floor, contents ride with the drawer and stay
remembered unseen."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rlgp_exec.executive.drawer_memory import KNOB_TOUCH_M, DrawerMemory
from rlgp_exec.executive.world import drawer_openings
from rlgp_exec.scene import load_scene

SCENE = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "table_clearing_hsr.toml"


def _memory() -> DrawerMemory:
    return DrawerMemory(load_scene(SCENE))


def test_the_drawer_follows_the_hand_along_its_axis_within_its_travel():
    m = _memory()
    g = m.cabinets["cabinet"]
    p_knob = m.knob_position("cabinet")
    near = m.nearest_knob(p_knob + np.array([0.0, 0.0, KNOB_TOUCH_M / 2]))
    assert near is not None and near[1] == "cabinet" and np.isclose(near[0], KNOB_TOUCH_M / 2)
    assert m.nearest_knob(p_knob + np.array([0.0, 0.0, 2 * KNOB_TOUCH_M])) is None
    m.take_knob("cabinet", p_knob, {})
    sideways = np.cross(g.axis_world, [0.0, 0.0, 1.0])
    p = p_knob + 0.2 * g.axis_world + 0.05 * sideways  # a sideways slip does not open it further
    assert np.isclose(m.opening_now(p), 0.2)
    assert np.isclose(m.opening_now(p_knob + 1.0 * g.axis_world), g.travel)  # clamped to the travel
    assert np.isclose(m.opening_now(p_knob - 0.1 * g.axis_world), 0.0)  # cannot push it in beyond closed
    frames = m.frames(p)
    assert np.isclose(drawer_openings(load_scene(SCENE), frames)["cabinet"], 0.2)  # what the executive reads
    m.release_knob(p)
    assert m.knob is None and np.isclose(m.openings["cabinet"], 0.2)
    assert np.allclose(m.knob_position("cabinet"), p_knob + 0.2 * g.axis_world)


def test_a_drop_over_the_open_drawer_rests_on_its_floor_and_rides_with_it_when_closed():
    m = _memory()
    g = m.cabinets["cabinet"]
    p_knob = m.knob_position("cabinet")
    m.take_knob("cabinet", p_knob, {})
    m.release_knob(p_knob + 0.25 * g.axis_world)
    T_inner = m.T_world_drawer("cabinet") @ g.inner_box.T
    T_let_go = np.eye(4)
    T_let_go[:3, 3] = T_inner[:3, 3] + [0.0, 0.0, 0.2]  # above the drawer's middle
    T = m.settle("cup", T_let_go)
    floor_z = T_inner[2, 3] - g.inner_box.size[2] / 2
    assert np.isclose(T[2, 3], floor_z + 0.04)  # the cup (8 cm tall) stands on the floor
    assert np.allclose(T[:2, 3], T_let_go[:2, 3])
    assert m.in_drawer("cabinet", T[:3, 3]) and m.hidden(T[:3, 3])
    away = T_let_go.copy()
    away[:3, 3] += 1.0 * np.cross(g.axis_world, [0.0, 0.0, 1.0])
    assert m.settle("cup", away) is away  # not over the drawer: where it was let go
    # close it: the cup rides along and ends inside the closed drawer, still hidden
    p_knob = m.knob_position("cabinet")
    m.take_knob("cabinet", p_knob, {"cup": T})
    assert m.knob is not None and m.knob.contents == ("cup",)
    p_closed = p_knob - 0.25 * g.axis_world
    shift = m.shift(m.opening_now(p_closed))
    assert np.allclose(shift, -0.25 * g.axis_world)
    assert m.release_knob(p_closed) == ("cup",)
    assert np.isclose(m.openings["cabinet"], 0.0)
    assert m.hidden(T[:3, 3] + shift)


def test_an_object_in_the_open_outside_any_cabinet_is_not_hidden():
    scene = load_scene(SCENE)
    m = DrawerMemory(scene)
    for o in scene.objects:
        assert not m.hidden(o.T[:3, 3]), o.name


def test_a_drawer_sensed_a_hair_beyond_its_stop_is_at_its_stop():
    """Physics leaves a fully opened drawer 1e-6 m beyond its travel: read as the travel, not an error
    (a renderer refused that opening for every frame after)."""
    scene = load_scene(SCENE)
    m = DrawerMemory(scene)
    g = m.cabinets["cabinet"]
    for sensed, read in ((g.travel + 1e-6, g.travel), (-1e-6, 0.0), (0.1, 0.1)):
        assert np.isclose(drawer_openings(scene, {"cabinet.drawer": g.T_world_drawer(sensed)})["cabinet"], read)
