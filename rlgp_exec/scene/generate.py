"""Generated scenes: sorting N blocks onto two trays, for ``bench scaling`` and for tests.

``sorting_scene(robot, n, seed)`` is the R-LGP paper's sorting task grown to ``n`` blocks: a middle
table (PR2: 1.2 x 1.6 m; HSR: 1.0 x 0.5 m, every block within the arm's reach from a long side), two
side tables ~2 m (PR2) / ~1.5 m (HSR) away carrying a blue and a green tray, blocks alternately blue
and green, placed by :func:`randomize` with ``seed``, ``GAP`` apart. Same arguments, same scene.
"""

from __future__ import annotations

from typing import Any

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.loader import scene_from_dict
from rlgp_exec.scene.randomize import randomize
from rlgp_exec.scene.types import Scene

__all__ = ["GAP", "MAX_SORTING_OBJECTS", "ROBOTS", "sorting_scene"]

ROBOTS = ("pr2", "hsr")
MAX_SORTING_OBJECTS = 12  # two 0.3 m trays hold 6 blocks of 5 cm each with room to place them
GAP = 0.03  # [m] between blocks: room for the fingers on every side (tight gaps are the clutter scenes')


def _layout(robot: str) -> dict[str, Any]:
    """Fixtures, trays, block size and randomisation box of the two robots' sorting scenes."""
    if robot == "pr2":
        return {
            "base": [0.0, -1.3, 1.5708], "joints": {"torso_lift_joint": 0.2},
            "mid": ([1.2, 1.6, 0.72], [0.0, 0.0, 0.36, 0.0]),
            "sides": ([0.6, 0.8, 0.72], [2.0, -0.4], [-2.0, 0.4]), "tray": [0.3, 0.3],
            "block": [0.05, 0.05, 0.10], "x": [-0.5, 0.5], "y": [-0.7, 0.7],
        }
    return {
        "base": [0.0, -1.0, 1.5708], "joints": {},
        "mid": ([1.0, 0.5, 0.45], [0.0, 0.0, 0.225, 0.0]),
        "sides": ([0.5, 0.5, 0.45], [1.5, -0.7], [-1.5, 0.7]), "tray": [0.25, 0.25],
        "block": [0.05, 0.05, 0.08], "x": [-0.42, 0.42], "y": [-0.17, 0.17],
    }


def sorting_scene(robot: str, n: int, seed: int = 0) -> Scene:
    """Sorting ``n`` blocks (``n`` in 1..MAX_SORTING_OBJECTS) onto two trays, layout drawn with ``seed``."""
    if robot not in ROBOTS:
        raise SceneError("<sorting_scene>", "robot", f"unknown robot {robot!r}; valid: {list(ROBOTS)}")
    if not 1 <= n <= MAX_SORTING_OBJECTS:
        raise SceneError("<sorting_scene>", "n", f"{n} blocks; valid: 1..{MAX_SORTING_OBJECTS} (two trays)")
    L = _layout(robot)
    mid_size, mid_pose = L["mid"]
    side_size, blue_xy, green_xy = L["sides"]
    top = mid_size[2]
    h = L["block"][2]
    colours = ("blue", "green")
    objects, goal = [], []
    for i in range(n):
        c = colours[i % 2]
        name = f"block_{c}_{i // 2}"
        # a deterministic start row, then randomize() draws the real layout
        x = L["x"][0] + (i + 0.5) * (L["x"][1] - L["x"][0]) / n
        objects.append({
            "name": name, "size": L["block"], "pose": [x, 0.0, top + h / 2, 0.0], "color": c,
            "tag": {"id": i + 1, "size": 0.04},
            "random": {"x": L["x"], "y": L["y"], "yaw": [-1.57, 1.57]},
        })
        goal.append(f"(on {name} tray_{c})")
    data = {
        "scene": {"name": f"sorting{n}_{robot}", "robot": robot},
        "robot": {"base": L["base"], **({"joints": L["joints"]} if L["joints"] else {})},
        "fixture": [
            {"name": "table_mid", "size": mid_size, "pose": mid_pose, "color": "grey"},
            {"name": "table_blue", "size": side_size, "pose": [*blue_xy, top / 2, 0.0], "color": "wood"},
            {"name": "table_green", "size": side_size, "pose": [*green_xy, top / 2, 0.0], "color": "wood"},
        ],
        "region": [
            {"name": "tray_blue", "on": "table_blue", "size": L["tray"], "color": "blue"},
            {"name": "tray_green", "on": "table_green", "size": L["tray"], "color": "green"},
        ],
        "object": objects,
        "goal": {"literals": goal},
    }
    return randomize(scene_from_dict(data, f"<sorting_scene {robot} n={n} seed={seed}>"), seed, GAP)
