"""Plan a shipped task with R-LGP and time it as the executive would.

    python examples/01_plan_a_shipped_scene.py [SCENE]   (default: pick_place_pr2)
"""

import sys

import rlgp_exec as rx

name = sys.argv[1] if len(sys.argv) > 1 else "pick_place_pr2"
scene = rx.shipped_scene(name)
plan = rx.plan(scene, planner="rlgp", seed=0)
print(f"{scene.name}: {'planned' if plan.success else 'failed'} in {plan.planning_time_s:.2f} s: {plan.reason}")
if not plan.success:
    sys.exit(1)
print("actions:", " ".join(plan.actions))
assert plan.validation is not None  # a successful plan has been replayed: collision-free, goal met
print(f"replay: collision-free {plan.validation.collision_free}, goal met {plan.validation.goal_met}")

timed = rx.to_trajectory(plan, scene.robot.name)
moving = [t for t in timed.trajectories if t is not None]
print(f"{len(moving)} timed motions, {timed.duration_s:.1f} s in all; base path {plan.base_path_length_m:.2f} m")
