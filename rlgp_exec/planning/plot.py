"""Top views of planned trajectories (R-LGP paper, Fig. 5 style): the scene's fixtures, regions and
objects from above, and each run's base path (x, y) [m] as a yellow line, one panel per planner
(:func:`plot_base_paths`); one plan's base and tool paths with where each action happens, numbered and
labelled (:func:`plot_plan`: a fixed-base plan shows its arm's motion, not a single point).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from rlgp_exec.planning.plan import Plan
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Box, fixture_boxes, object_box, region_box

__all__ = ["plot_base_paths", "plot_plan"]

log = logging.getLogger(__name__)


def _rect(ax, b: Box, **kw) -> None:
    # local: matplotlib (~0.7 s) loads only when a plot is drawn
    from matplotlib.patches import Polygon

    hx, hy = b.size[0] / 2, b.size[1] / 2
    corners = np.array([[hx, hy], [-hx, hy], [-hx, -hy], [hx, -hy]]) @ b.T[:2, :2].T + b.T[:2, 3]
    ax.add_patch(Polygon(corners, closed=True, **kw))


def _draw_scene(ax, scene: Scene) -> None:
    for fx in scene.fixtures:
        for b in fixture_boxes(fx):
            _rect(ax, b, facecolor=b.color[:3], edgecolor="k", linewidth=0.5, alpha=0.6)
    for r in scene.regions:
        b = region_box(scene, r)
        _rect(ax, b, facecolor=b.color[:3], edgecolor="k", linewidth=0.5, alpha=0.9)
    for o in scene.objects:
        b = object_box(o)
        _rect(ax, b, facecolor=b.color[:3], edgecolor="k", linewidth=0.8)


def _save(fig, out: str | Path) -> Path:
    # local: after matplotlib.use("Agg"), which must come first
    import matplotlib.pyplot as plt

    fig.tight_layout()
    path = Path(out)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    log.info("wrote %s", path)
    return path


def plot_plan(scene: Scene, plan: Plan, model: RobotModel, out: str | Path, title: str = "") -> Path:
    """Write a top view of one plan: the base path (gold), each arm's tool path (blue), and a numbered
    marker where each action ends (its keyframe's tool position), the actions listed beside the plot."""
    # local: matplotlib (~0.7 s) loads only when a plot is drawn
    import matplotlib

    matplotlib.use("Agg")
    # local: after matplotlib.use("Agg"), which must come first
    import matplotlib.pyplot as plt

    fig, (ax, key) = plt.subplots(1, 2, figsize=(10.5, 6.0), gridspec_kw={"width_ratios": [3, 1.4]})
    _draw_scene(ax, scene)
    base = scene.robot.base
    ax.plot(base[0], base[1], "s", color="k", markersize=6, label="base start")
    qs = [ph.path for ph in plan.phases if len(ph.path)]
    if qs:
        q = np.concatenate(qs)
        ax.plot(q[:, 0], q[:, 1], color="gold", linewidth=2.0, label="base path")
        for arm in {ph.arm for ph in plan.phases}:
            frame = model.manipulator(arm).tool_frame
            xyz = np.array([model.fk(qi, frame)[:3, 3] for qi in q])
            ax.plot(xyz[:, 0], xyz[:, 1], color="tab:blue", linewidth=1.0, alpha=0.8,
                    label=f"tool path ({arm or model.manipulator().name})")
    done: set[int] = set()
    for ph in plan.phases:
        a = ph.action
        if a is None or a in done or not len(ph.path):
            continue
        done.add(a)
        xyz = model.fk(ph.path[-1], model.manipulator(ph.arm).tool_frame)[:3, 3]
        ax.plot(xyz[0], xyz[1], "o", color="tab:red", markersize=7, markeredgecolor="k")
        ax.annotate(str(a + 1), (xyz[0], xyz[1]), textcoords="offset points", xytext=(5, 5), fontsize=9,
                    fontweight="bold", color="tab:red")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.grid(True, linewidth=0.3)
    ax.legend(loc="best", fontsize=7)
    ax.set_title(title or f"{scene.name}: {plan.planner}")
    key.axis("off")
    lines = [f"{i + 1}. {act}" for i, act in enumerate(plan.actions)] or ["(no actions)"]
    if not plan.success:
        lines.append(f"FAILED: {plan.reason[:60]}")
    key.text(0.0, 1.0, "\n".join(lines), va="top", ha="left", fontsize=8, family="monospace", wrap=True)
    return _save(fig, out)


def plot_base_paths(scene: Scene, paths: Mapping[str, Sequence[FloatArray]], out: str | Path, title: str = "") -> Path:
    """Write a PNG with one panel per planner; ``paths[planner]`` holds (n, 2) base paths [m]."""
    # local: matplotlib (~0.7 s) loads only when a plot is drawn
    import matplotlib

    matplotlib.use("Agg")
    # local: after matplotlib.use("Agg"), which must come first
    import matplotlib.pyplot as plt

    names = list(paths) or ["(no runs)"]
    fig, axes = plt.subplots(1, len(names), figsize=(5.5 * len(names), 5.5), squeeze=False)
    for ax, name in zip(axes[0], names, strict=True):
        _draw_scene(ax, scene)
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
    return _save(fig, out)
