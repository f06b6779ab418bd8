"""Pictures of a reachability graph (as the paper's Fig. 7): nodes, edges, a guided path, and what a
batch of queries added, in a top view and a side view, before and after."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.reach.graph import ReachabilityGraph
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import fixture_boxes

__all__ = ["GraphSnapshot", "draw_graph_png"]

GREY, EDGE, NODE, NEW, PATH, INK = (
    (200, 200, 200),
    (190, 170, 150),
    (160, 90, 30),
    (0, 140, 255),
    (40, 40, 220),
    (60, 60, 60),
)


class GraphSnapshot:
    """The nodes and edges of a graph at one moment."""

    def __init__(self, g: ReachabilityGraph) -> None:
        self.nodes = set(int(i) for i in g.G.nodes)
        self.edges = {(min(u, v), max(u, v)) for u, v in g.G.edges}


def _panel(
    g: ReachabilityGraph,
    scene: Scene,
    axes: tuple[int, int],
    size: tuple[int, int],
    lo: np.ndarray,
    hi: np.ndarray,
    before: GraphSnapshot | None,
    path: np.ndarray | None,
    title: str,
) -> np.ndarray:
    w, h = size
    img = np.full((h, w, 3), 255, np.uint8)
    a, b = axes
    scale = min((w - 40) / (hi[a] - lo[a]), (h - 60) / (hi[b] - lo[b]))

    def px(p: np.ndarray) -> tuple[int, int]:
        return int(20 + (p[a] - lo[a]) * scale), int(h - 20 - (p[b] - lo[b]) * scale)

    for fx in scene.fixtures:
        for box in fixture_boxes(fx):
            corners = (
                np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)])
                * np.asarray(box.size)
                / 2
            )
            pts = (box.T[:3, :3] @ corners.T).T + box.T[:3, 3]
            hull = cv2.convexHull(np.array([px(p) for p in pts], np.int32))
            cv2.fillConvexPoly(img, hull, GREY)
    for u, v in g.G.edges:
        new = before is not None and (min(u, v), max(u, v)) not in before.edges
        cv2.line(img, px(g.X[u]), px(g.X[v]), NEW if new else EDGE, 1, cv2.LINE_AA)
    for i in g.G.nodes:
        new = before is not None and int(i) not in before.nodes
        cv2.circle(img, px(g.X[i]), 3 if new else 2, NEW if new else NODE, -1, cv2.LINE_AA)
    if path is not None and len(path) > 1:
        pts = np.array([px(p) for p in path], np.int32)
        cv2.polylines(img, [pts], False, PATH, 2, cv2.LINE_AA)
    cv2.putText(img, title, (10, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.55, INK, 1, cv2.LINE_AA)
    return img


def draw_graph_png(
    g: ReachabilityGraph,
    scene: Scene,
    out: str | Path,
    before: GraphSnapshot,
    path_x: np.ndarray | None = None,
    before_graph: ReachabilityGraph | None = None,
) -> Path:
    """A 2x2 PNG: top and side views (columns) of the graph before (top row: ``before_graph``) and after
    the queries (bottom row: nodes/edges added since ``before`` in orange, ``path_x`` (n, 3) in red)."""
    if g.G.number_of_nodes() == 0:
        raise RlgpError("the reachability graph is empty: nothing to draw")
    pts = g.X[g.alive]
    lo, hi = pts.min(axis=0) - 0.2, pts.max(axis=0) + 0.2
    lo[2], hi[2] = 0.0, max(hi[2], 1.2)
    size = (640, 400)
    rows = []
    for graph, snap, label in ((before_graph, None, "before"), (g, before, "after")):
        if graph is None:
            continue
        rows.append(
            np.hstack(
                [
                    _panel(
                        graph, scene, (0, 1), size, lo, hi, snap, path_x if snap else None, f"{label}: top view (x, y)"
                    ),
                    _panel(
                        graph, scene, (0, 2), size, lo, hi, snap, path_x if snap else None, f"{label}: side view (x, z)"
                    ),
                ]
            )
        )
    img = np.vstack(rows)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), img):
        raise RlgpError(f"could not write {out}")
    return out
