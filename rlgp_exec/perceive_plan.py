"""Perception to plan on a paper task: the scene file is wrong, the head camera finds where the tagged
objects really are, a planner plans on what was perceived, and the plan is checked in the *true* world.

The true world is the scene file with its tagged objects moved up to ``perturb_m`` (as on a real
robot, the file is only a prior). The plan is validated twice: by the planner on the perceived scene
(as always), then here by replaying it in PyBullet in the true world (collisions, goal). A plan that
only works in the robot's belief fails the second check.

This is what the numbered ``tools/1x_*.py`` scripts run, one per paper task.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.validate import Validation, validate_plan
from rlgp_exec.scene import load_scene

__all__ = ["PerceivePlanReport", "perceive_and_plan"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PerceivePlanReport:
    scene: str
    planner: str
    views: int  # camera images taken
    errors_mm: dict[str, float]  # per tagged object: perceived vs true position [mm]
    unseen: tuple[str, ...]  # tagged objects perception did not find (they keep their file poses)
    perceive_s: float  # [s] wall time (one perception serves every planner of a call)
    plan: Plan
    in_truth: Validation | None  # the plan replayed in the true world; None if there is no plan

    @property
    def ok(self) -> bool:
        return self.plan.success and self.in_truth is not None and self.in_truth.ok

    def text(self) -> str:
        errs = ", ".join(f"{n} {e:.1f} mm" for n, e in sorted(self.errors_mm.items()))
        lines = [
            f"{self.scene}: {self.views} camera views in {self.perceive_s:.1f} s; perceived {errs}",
            *(f"  not seen (file pose kept): {n}" for n in self.unseen),
            f"{self.planner}: {'plan' if self.plan.success else 'no plan'} in {self.plan.planning_time_s:.2f} s "
            f"({self.plan.n_nlp} NLPs), {len(self.plan.actions)} steps, base path {self.plan.base_path_length_m:.2f} m",
            *(f"  {a}" for a in self.plan.actions),
        ]
        if not self.plan.success:
            lines.append(f"  reason: {self.plan.reason}")
        elif self.in_truth is not None:
            v = self.in_truth
            lines.append(
                "in the true world: "
                + ("collision-free" if v.collision_free else f"collisions {list(v.collisions)[:3]}")
                + (", goal met" if v.goal_met else ", goal NOT met")
            )
        lines.append("result: " + ("OK" if self.ok else "FAILED"))
        return "\n".join(lines)


def perceive_and_plan(
    scene_file: str | Path, planners: Sequence[str] = ("rlgp",), seed: int = 0, perturb_m: float = 0.03
) -> list[PerceivePlanReport]:
    """Perceive ``scene_file``'s world once (objects moved by up to ``perturb_m`` [m], seeded), plan on
    the perceived scene with each of ``planners`` and replay each plan in the true world."""
    # local: perception.runner and planning.registry bring SciPy and OpenCV
    from rlgp_exec.perception.runner import perceive_scene, perturbed_scene
    from rlgp_exec.planning.registry import plan as run_planner

    # local: world.pybullet_world brings OpenCV
    from rlgp_exec.world.pybullet_world import build_world

    scene = load_scene(scene_file)
    truth = perturbed_scene(scene, perturb_m, seed)
    world = build_world(truth, tags=False)
    try:
        bad = world.penetrations()
    finally:
        world.close()
    if bad:
        raise RlgpError(f"{scene.name}: objects moved {perturb_m} m with seed {seed} collide: {bad}; use another seed")
    t0 = time.perf_counter()
    seen = perceive_scene(scene, perturb_m=perturb_m, seed=seed)
    perceive_s = time.perf_counter() - t0
    reports = []
    for planner in planners:
        plan = run_planner(seen.scene, planner, seed=seed)
        in_truth = validate_plan(truth, plan.phases) if plan.success else None
        reports.append(
            PerceivePlanReport(
                scene.name,
                planner,
                seen.views,
                dict(seen.errors_mm),
                tuple(sorted(seen.missing)),
                perceive_s,
                plan,
                in_truth,
            )
        )
    return reports
