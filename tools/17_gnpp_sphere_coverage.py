"""17 — how well GNPP's collision spheres cover an arm's links: points of each link's PyBullet collision hull
outside every sphere the fixture rows use, and how far outside.

    .venv/bin/python tools/17_gnpp_sphere_coverage.py [SCENE] [--arm right_arm] [--configs 20] [--seed 0]

At ``--configs`` random configurations of the arm (within its NLP bounds), each link's hull surface is
sampled by probing: a 1 mm sphere 0.5 m from the link's centre on 64 bearings, PyBullet's closest point on
the link to it (``getClosestPoints(..., linkIndexA=link)``). A surface point p is covered when some sphere
(centre c, radius r) of ``FactorLib.arm_shapes(arm)`` in the ``fixture`` set has |p - c| <= r; otherwise
it sticks out by |p - c| - r for the nearest such sphere. A keyframe whose fixture rows sit at their bound
(0 mm) can have that link enter a fixture by up to that much. Printed per link: the fraction of points
outside and the worst overhang [mm] (median and maximum over the configurations).

The raw figure counts the whole hull: a link's part that never comes near a fixture (the PR2 upper arm's
shoulder end, always high) counts as much as its underside. Measured (tower_pr2, right arm, 10 configurations):
upper arm 98 % of its points outside, up to 174 mm (the shoulder housing); elbow and forearm 93-97 %, ~40 mm;
fingers and tips 69-84 %, 42-49 mm (only the 1.1 cm spheres at the tips face the fixtures); palm 62 %,
14 mm; the wrist covered. The upper arm's one sphere (8 cm at mid-link) under-covers its underside, whose
hull reaches 9.8 cm from the shoulder-elbow axis: a pick keyframe of obstacles_tower_pr2 had it 9.6 mm
inside the table with 12 mm to spare on every row.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pybullet as p

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.planning.gnpp.geometry import FactorLib  # noqa: E402
from rlgp_exec.robot import load_robot  # noqa: E402
from rlgp_exec.scene import load_scene  # noqa: E402
from rlgp_exec.world.pybullet_world import build_world  # noqa: E402

BEARINGS = 64
PROBE_R = 0.5  # [m] from the link's centre


def _bearings(n: int) -> np.ndarray:
    """(n, 3) unit vectors spread over the sphere (a Fibonacci lattice)."""
    k = np.arange(n) + 0.5
    z = 1.0 - 2.0 * k / n
    phi = np.pi * (1.0 + 5**0.5) * k
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(phi), s * np.sin(phi), z], axis=1)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "sim" / "scenes" / "tower_pr2.toml"))
    ap.add_argument("--arm", default=None, help="the manipulator (default: the robot's first)")
    ap.add_argument("--configs", type=int, default=20)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    scene = load_scene(args.scene)
    lib = FactorLib(load_robot(scene.robot.name), scene)
    arm = args.arm or lib.arms[0]
    if arm not in lib.arms:
        raise SystemExit(f"unknown arm {arm!r}; valid: {list(lib.arms)}")
    shapes = lib.arm_shapes(arm)
    radii = np.asarray(shapes.radii)[list(shapes.fixture)]
    world = build_world(replace(scene, objects=()), tags=False)
    robot, client = world.robot, world.client
    moved = set(lib.model.manipulator(arm).links) | {
        n for n in robot.link_index if n.startswith(arm[0] + "_") and any(k in n for k in ("arm", "wrist", "elbow"))
    }
    links = sorted(n for n in moved if p.getCollisionShapeData(robot.id, robot.link_index[n], physicsClientId=client))
    probe = p.createMultiBody(0, p.createCollisionShape(p.GEOM_SPHERE, radius=0.001, physicsClientId=client),
                              -1, [0, 0, 10], physicsClientId=client)
    lo, hi = lib.var_bounds("q", arm)
    rng = np.random.default_rng(args.seed)
    dirs = _bearings(BEARINGS)
    out: dict[str, list[tuple[float, float]]] = {n: [] for n in links}
    try:
        for _ in range(args.configs):
            q = rng.uniform(lo, hi)
            robot.set_q(lib.full_q({arm: q}))
            centres = np.asarray(shapes.fn(q)[0])[:, list(shapes.fixture)].T
            for name in links:
                i = robot.link_index[name]
                a, b = (np.asarray(v) for v in p.getAABB(robot.id, i, physicsClientId=client))
                mid, pts = 0.5 * (a + b), []
                for d in dirs:
                    p.resetBasePositionAndOrientation(probe, (mid + PROBE_R * d).tolist(), [0, 0, 0, 1],
                                                      physicsClientId=client)
                    cps = p.getClosestPoints(robot.id, probe, 2 * PROBE_R, linkIndexA=i, physicsClientId=client)
                    pts += [c[5] for c in cps]
                if not pts:
                    continue
                over = (np.linalg.norm(np.asarray(pts)[:, None] - centres[None], axis=2) - radii[None]).min(axis=1)
                out[name].append((float(np.mean(over > 0.0)), float(max(over.max(), 0.0))))
    finally:
        world.close()
    print(f"{scene.name}, {arm}: {len(radii)} fixture spheres, {args.configs} configurations, {BEARINGS} bearings")
    print(f"{'link':34s} {'outside':>8s} {'overhang median':>16s} {'max [mm]':>9s}")
    for name in links:
        if not out[name]:
            continue
        frac, worst = np.array(out[name]).T
        print(f"{name:34s} {np.mean(frac):8.1%} {1e3 * np.median(worst):16.1f} {1e3 * worst.max():9.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
