"""Top views of planned base trajectories (R-LGP paper, Fig. 5 style): the scene's fixtures, regions
and objects from above, and each run's base path (x, y) [m] as a yellow line, one panel per planner.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Box, fixture_boxes, object_box, region_box

__all__ = ["plot_base_paths"]

log = logging.getLogger(__name__)


def _rect(ax, b: Box, **kw) -> None:
    from matplotlib.patches import Polygon

    hx, hy = b.size[0] / 2, b.size[1] / 2
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]]) @ b.T[:2, :2].T + b.T[:2, 3]
    ax.add_patch(Polygon(corners, closed=True, **kw))


def plot_base_paths(scene: Scene, paths: Mapping[str, Sequence[FloatArray]], out: str | Path, title: str = "") -> Path:
    """Write a PNG with one panel per planner; ``paths[planner]`` holds (n, 2) base paths [m]."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = list(paths) or ["(no runs)"]
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 5.5), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        for fx in scene.fixtures:
            for b in fixture_boxes(fx):
                _rect(ax, b, facecolor=b.color[:3], edgecolor="k", linewidth=0.5, alpha=0.6)
        for r in scene.regions:
            b = region_box(scene, r)
            _rect(ax, b, facecolor=b.color[:3], edgecolor="k", linewidth=0.5, alpha=0.9)
        for o in scene.objects:
            b = object_box(o)
            _rect(ax, b, facecolor=b.color[:3], edgecolor="k", linewidth=0.8)
        runs = paths.get(name, [])
        for xy in runs:
            xy = np.asarray(xy, float)
            if len(xy):
                ax.plot(xy[:, 0], xy[:, 1], color="gold", linewidth=1.5, alpha=0.8)
                ax.plot(xy[0, 0], xy[0, 1], "o", color="k", markersize=4)
        base = scene.robot.base
        ax.plot(base[0], base[1], "s", color="k", markersize=6)
        ax.set_aspect("equal")
        ax.set_title(f"{name}: {len(runs)} successful run(s)")
        ax.set_xlabel("x [m]")
        ax.set_ylabel("y [m]")
        ax.grid(True, linewidth=0.3)
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)
    log.info("wrote %s", out)
    return out
