"""Build (or load) the reachability graph of a scene, ask it for paths, and draw it.

    .venv/bin/python tools/02_reachability_graph.py [SCENE] [--png out/rg.png]

The graph is cached per environment under ~/.cache/rlgp-exec/reachability (or $RLGP_EXEC_CACHE):
the second run loads it instead of building.
"""

from __future__ import annotations

import argparse
import copy
from pathlib import Path

import numpy as np

from rlgp_exec.reach import (
    GraphSnapshot,
    ReachabilityPlanner,
    ReachIK,
    RGParams,
    WorldChecker,
    draw_graph_png,
    load_or_build,
    nominal_q,
)
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene

ROOT = Path(__file__).resolve().parent.parent


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("scene", nargs="?", default=str(ROOT / "sim" / "scenes" / "sorting_hsr.toml"))
    ap.add_argument("--png", default=str(ROOT / "out" / "reachability.png"))
    args = ap.parse_args()
    scene = load_scene(args.scene)
    model = load_robot(scene.robot.name)
    graph, stats = load_or_build(scene, params=RGParams(samples=200))
    print(f"graph: {graph.G.number_of_nodes()} nodes, {graph.G.number_of_edges()} edges, "
          f"{'loaded' if stats.from_cache else 'built'} in {stats.build_time_s:.2f} s")
    before, before_graph = GraphSnapshot(graph), copy.deepcopy(graph)
    checker = WorldChecker(scene, model.manipulator().group)
    planner = ReachabilityPlanner(graph, ReachIK(model, scene, nominal_q(model, scene)), checker)
    # from where the robot's hand is at the start to each object, and back (the second is a library hit)
    tool = model.manipulator().tool_frame
    q0 = nominal_q(model, scene)
    x0 = model.fk(q0, tool)[:3, 3]
    longest = None
    for obj in scene.objects:
        x = np.asarray(obj.pose[:3]) + np.array([0.0, 0.0, obj.size[2] / 2 + 0.05])
        there = planner.query(x0, x)
        back = planner.query(x, x0)
        print(f"  hand -> above {obj.name:14s} {there.status.value:18s} {len(there.path):3d} waypoints, "
              f"h = {there.cost:7.2f}, {there.query_ms:6.1f} ms; back: cached={back.cached} {back.query_ms:.3f} ms")
        if there.ok and (longest is None or len(there.path) > len(longest)):
            longest = there.path
    path_x = None if longest is None else np.array([model.fk(q, tool)[:3, 3] for q in longest])
    print(f"wrote {draw_graph_png(graph, scene, args.png, before, path_x, before_graph)}")
    checker.close()


if __name__ == "__main__":
    main()
