"""GNPP's repair of a plan's moves that collide in the replay (``gnpp.repair``), and ``GraphSolver.polish``."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.guess import TopIK
from rlgp_exec.planning.gnpp.motion import Transit
from rlgp_exec.planning.gnpp.repair import repair_transits
from rlgp_exec.planning.validate import Phase
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"


@pytest.fixture(scope="module")
def lib():
    return FactorLib(load_robot("pr2"), load_scene(SCENES / "obstacles_tower_pr2.toml"))


def test_a_move_through_a_block_is_planned_again_round_it(lib):
    """The right hand's straight move between two top grasps, a block standing where the hand passes
    halfway: the move fails the exact edge check; the repaired phase keeps its ends and every segment of
    it passes the check with the block where it stands. A phase the replay did not name is left alone; a
    move that passes the check is not planned again (None: nothing repaired)."""
    from rlgp_exec.reach import WorldChecker
    from rlgp_exec.scene.geometry import object_box

    ik, arm = TopIK(lib), "right_arm"
    (ok_a, qa), (ok_b, qb) = (ik.solve(arm, np.array(pt), lib.home_q(arm)) for pt in [(0.05, -0.35, 0.85),
                                                                                        (0.3, -0.05, 0.85)])
    assert ok_a and ok_b
    mid = lib.tool_T(arm, 0.5 * (qa + qb))[:3, 3]
    block = "o1"
    resting = {block: np.array([mid[0], mid[1], mid[2], 0.0])}
    a, b = lib.full_q({arm: qa}), lib.full_q({arm: qb})
    phases = [Phase(np.array([a, b]), None, arm=arm), Phase(np.array([a, b]), None, arm=arm)]
    transits = [Transit(0, 0, arm, None, resting), Transit(1, 0, arm, None, resting)]
    checker = WorldChecker(lib.scene, lib.model.manipulator(arm).group, manipulator=arm)
    try:
        checker.set_objects([replace(object_box(lib.objects[block]), T=lib.object_T(resting[block]))])
        assert checker.edge_collides(a, b)
        out = repair_transits(lib, phases, transits, ["phase 1: robot r_gripper_palm_link ~ o1"])
        assert out is not None
        assert out[0] is phases[0]
        path = out[1].path
        assert len(path) > 2 and np.allclose(path[0], a) and np.allclose(lib.model.limits.difference(path[-1], b), 0.0)
        assert not any(checker.edge_collides(u, v) for u, v in itertools.pairwise(path))
    finally:
        checker.close()
    assert repair_transits(lib, phases, transits, ["phase 0: robot r_upper_arm_link ~ table"]) is not None
    still = [Phase(np.array([a, a]), None, arm=arm)]  # a move that does not move: nothing to repair
    assert repair_transits(lib, still, transits[:1], ["phase 0: robot r_upper_arm_link ~ table"]) is None


def test_the_sphere_coverage_tool_reports_every_link_with_a_hull():
    """``tools/17_gnpp_sphere_coverage.py``: a row per arm link with a collision shape, its fraction of hull
    points outside every fixture sphere within [0, 1] and an overhang that is 0 where nothing sticks out."""
    import subprocess
    import sys

    tool = Path(__file__).resolve().parents[1] / "tools" / "17_gnpp_sphere_coverage.py"
    run = subprocess.run([sys.executable, str(tool), "--configs", "2"], capture_output=True, text=True, timeout=300,
                         check=False)
    assert run.returncode == 0, run.stderr[-2000:]
    rows = [line.split() for line in run.stdout.splitlines() if line.startswith("r_")]
    assert {"r_upper_arm_link", "r_forearm_link", "r_gripper_palm_link"} <= {r[0] for r in rows}
    for name, frac, median, worst in rows:
        f = float(frac.rstrip("%")) / 100
        assert 0.0 <= f <= 1.0 and 0.0 <= float(median) <= float(worst), name
        assert (f == 0.0) == (float(worst) == 0.0), name


def test_repair_goes_round_after_round_until_the_replay_passes(monkeypatch):
    """The replay stops at its first collision, so each round repairs one phase: phase 1, then phase 3 (found
    only once 1 passes), then the replay passes. A phase that collides again after its repair, or a move
    that cannot be repaired, ends the rounds with the replay's verdict as it stands."""
    from rlgp_exec.planning.gnpp import repair
    from rlgp_exec.planning.validate import Validation

    def verdict(*collisions: str) -> Validation:
        return Validation(not collisions, True, collisions, (), {})

    def run(replays: list[Validation], repairable: bool = True) -> tuple[Validation, list[tuple[int, ...]]]:
        calls: list[tuple[int, ...]] = []

        def fake_repair(lib, phases, transits, collisions):
            calls.append(tuple(sorted(repair.collided_phases(collisions))))
            return list(phases) if repairable else None

        monkeypatch.setattr(repair, "repair_transits", fake_repair)
        monkeypatch.setattr(repair, "validate_with_fallbacks", lambda sc, ph, fb: (replays.pop(0), ph, set()))
        v, _, _ = repair.repair_rounds(None, None, [], [], verdict("phase 1: robot a ~ table"), {}, set())
        return v, calls

    v, calls = run([verdict("phase 3: held o ~ table"), verdict()])
    assert v.collision_free and calls == [(1,), (3,)]
    v, calls = run([verdict("phase 3: held o ~ table"), verdict("phase 1: robot a ~ b")])
    assert not v.collision_free and v.collisions == ("phase 1: robot a ~ b",) and calls == [(1,), (3,)]
    v, calls = run([], repairable=False)
    assert not v.collision_free and calls == [(1,)]
