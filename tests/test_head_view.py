"""Head views: never a posture, nor a way there, that collides; a tag's expected size in the image."""

import math
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.executive.head_view import HeadView, HeadViews
from rlgp_exec.perception.camera import camera_for_robot
from rlgp_exec.robot.head import look_at_q, pointing_error
from rlgp_exec.robot.model import load_robot
from rlgp_exec.scene import load_scene

SCENE = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "sorting_hsr.toml"


@pytest.fixture(scope="module")
def hsr():
    model, scene = load_robot("hsr"), load_scene(SCENE)
    return model, scene, HeadViews(model, scene, camera_for_robot("hsr"))


def test_looking_down_at_the_table_would_hit_the_base_the_view_tilts_only_as_far_as_it_is_free(hsr):
    model, scene, views = hsr
    q = model.home(scene.robot.base)
    head = list(model.group("head"))
    block = np.array(scene.object("block_blue").pose[:3])

    assert views.collides(look_at_q(model, q, block))  # head_tilt_link into base_link, the lift down
    v = views.view(q, block)
    assert isinstance(v, HeadView) and v.shortened
    assert not views.collides(v.q) and views.in_frame(v.q, block)
    assert np.array_equal(np.delete(v.q, head), np.delete(q, head))  # only the head moves
    # the way there is free too
    assert not any(views.collides(q + s * (v.q - q)) for s in np.linspace(0.0, 1.0, 33))


def test_views_of_random_points_never_collide_and_point_at_them_or_say_why(hsr):
    model, scene, views = hsr
    rng = np.random.default_rng(3)
    q = model.home(scene.robot.base)
    kinds = set()
    for _ in range(25):
        point = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-1.8, 1.0), rng.uniform(0.0, 1.2)])
        v = views.view(q, point)
        if isinstance(v, str):
            kinds.add("none")
            assert "head" in v
            continue
        kinds.add("shortened" if v.shortened else "straight")
        assert not views.collides(v.q)
        assert views.in_frame(v.q, point) and (v.shortened or pointing_error(model, v.q, point) < math.radians(5))
    assert {"none", "straight"} <= kinds


def test_a_tag_looks_smaller_far_away_and_at_a_grazing_angle(hsr):
    model, scene, views = hsr
    q = model.home(scene.robot.base)
    T = model.fk(q, model.config.frames["camera"])
    below = T[:3, 3] - [0.0, 0.0, 0.5]
    near = T[:3, 3] + [0.0, 0.5, -0.5]
    far = T[:3, 3] + [0.0, 1.5, -0.5]
    sides = [views.tag_side_px(q, p, 0.04) for p in (below, near, far)]
    fx = camera_for_robot("hsr").fx
    assert sides[0] == pytest.approx(0.04 * fx / 0.5)  # straight below: no foreshortening
    assert sides[0] > sides[1] > sides[2] > 0.0
