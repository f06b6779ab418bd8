"""Objects the camera cannot see from where the robot stands: planned unverified, verified when seen."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.executive.camera_source import LookResult
from rlgp_exec.executive.executive import Executive
from rlgp_exec.executive.world import SimMocap
from rlgp_exec.hal import make_backend
from rlgp_exec.planning.validate import Phase
from rlgp_exec.scene import load_scene

SCENE = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "sorting_hsr.toml"
WHY = "block_green: ~6 px tag side from here, the detector needs >= 13 px"


class FarCamera(SimMocap):
    """The simulation's truth, but block_green is out of sight until ``near`` (a camera's view from the
    start base, where its tag is too small)."""

    near = False

    def poses(self):
        poses = super().poses()
        if not self.near:
            poses.pop("block_green", None)
        return poses

    def look_for(self, names, hal):
        missing = frozenset(n for n in names if n not in self.poses())
        undetectable = (("block_green", WHY),) if "block_green" in missing else ()
        return LookResult(frozenset(names) - missing, missing, frozenset(), 0, 0.0, "", undetectable)


@pytest.fixture
def sim():
    scene = load_scene(SCENE)
    hal = make_backend("sim", scene=scene)
    hal.configure()
    try:
        yield scene, hal
    finally:
        hal.shutdown()


def test_an_object_too_small_to_see_is_planned_unverified_and_verified_once_the_camera_sees_it(sim):
    scene, hal = sim
    src = FarCamera(hal)
    ex = Executive(hal, scene, src)
    events = []
    ex._event = lambda kind, **data: events.append((kind, data))  # type: ignore[method-assign]
    assert ex._look_for(scene.goal)
    assert ex.unverified == {"block_green": WHY}
    assert events[-1][0] == "look_for" and events[-1][1]["unverified"] == {"block_green": WHY}
    ex._verified(src.poses())  # not in view yet: still unverified
    assert set(ex.unverified) == {"block_green"}
    src.near = True
    ex._verified(src.poses())
    assert ex.unverified == {} and events[-1] == ("verified", {"object": "block_green"})
    assert list(ex.verified) == ["block_green"]
    # the world check compares it with the plan from now on: seen 3 cm off, it is a move
    hal.sim.push_object("block_green", 0.03, 0.0)
    phase = Phase(np.array([ex.model.home(scene.robot.base)]), None, grasp="block_green")
    check = ex._world_check(scene, [phase])
    v = check(0, phase, hal.read_state())  # type: ignore[arg-type]
    assert v is not None and v.monitor == "object_moved" and "block_green" in v.detail


def test_looking_again_finds_nothing_unverified_when_everything_is_seen(sim):
    scene, hal = sim
    src = FarCamera(hal)
    src.near = True
    ex = Executive(hal, scene, src)
    assert ex._look_for(scene.goal) and ex.unverified == {}
