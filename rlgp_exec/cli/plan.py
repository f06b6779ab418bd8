"""``plan`` (a scene's task, validated by replay; timed, plotted, animated) and ``show`` (a scene as a PNG)."""

from __future__ import annotations

import argparse
import time
from typing import TYPE_CHECKING, Any

from rlgp_exec import progress
from rlgp_exec.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    PLANNER_CHOICES,
    output_checks,
    plan_limits,
    say,
    scene_arg,
    write_json,
)
from rlgp_exec.cli.flags import (
    SCENE_HELP,
    animate_flags,
    command,
    gui_flag,
    json_flag,
    limit_flags,
    planner_flag,
)
from rlgp_exec.errors import RlgpError
from rlgp_exec.gui import show_plan
from rlgp_exec.progress import stage

if TYPE_CHECKING:
    from rlgp_exec.planning.limits import PlanLimits

__all__ = ["add_plan_commands", "cmd_plan", "cmd_show"]


def _budget_s(planner: str, limits: PlanLimits) -> float | None:
    """The CPU budget [s] ``planner`` plans under with ``limits`` (its own default when not given)."""
    if limits.time_budget_s is not None:
        return limits.time_budget_s
    if planner in ("rlgp", "lgp"):
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.planning.rlgp import TIME_BUDGET_S

        return TIME_BUDGET_S
    try:
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.planning.gnpp import BENCH_TIMEOUT_S
    except ImportError:
        return None
    return BENCH_TIMEOUT_S if planner.startswith("gnpp") or planner == "oneway" else None


def _timing_text(cpu_s: float, budget_s: float | None, wall_s: float) -> str:
    """``X s CPU (budget Y s CPU), Z s wall``: budgets are CPU time, so times are reported in it too."""
    budget = f" (budget {budget_s:g} s CPU)" if budget_s is not None else ""
    return f"{cpu_s:.2f} s CPU{budget}, {wall_s:.2f} s wall"


def cmd_plan(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.planning.budget import cpu_clock
    from rlgp_exec.scene import load_scene, randomize

    limits = plan_limits(args)  # bad limits are refused before the scene loads
    output_checks(args)
    scene = load_scene(scene_arg(args.scene))  # before the planners load: a bad file is refused at once
    if args.seed:  # seed 0 is the file as written, as in `bench`
        scene = randomize(scene, args.seed)
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.planning.registry import plan as run_planner

    if args.planner not in PLANNER_CHOICES:  # a name argparse has not seen (a test's argv): the same error
        raise RlgpError(f"unknown planner {args.planner!r}; valid: {list(PLANNER_CHOICES)}")
    budget = _budget_s(args.planner, limits)
    cpu0, wall0 = cpu_clock(), time.perf_counter()
    with progress.stage(f"planning {scene.name} with {args.planner}"
                        + (f" (budget {budget:g} s CPU)" if budget is not None else "")):
        plan = run_planner(scene, args.planner, seed=args.seed or 0, limits=limits)
    cpu_s, wall_s = cpu_clock() - cpu0, time.perf_counter() - wall0
    summary = plan.summary()
    summary.update(cpu_time_s=cpu_s, wall_time_s=wall_s, time_budget_s=budget)
    how = "found a valid plan" if plan.success else "failed"
    say(f"{scene.name}: {args.planner} {how} after {_timing_text(cpu_s, budget, wall_s)} "
        f"({plan.n_nlp} NLPs, {plan.nodes_expanded} nodes expanded)")
    for i, a in enumerate(plan.actions, start=1):
        say(f"  {i:2d}. {a}")
    if plan.success:
        say(f"  base path {plan.base_path_length_m:.2f} m; replay: collision-free, goal met")
    else:
        say(f"  reason: {plan.reason}")
    model = None
    if plan.success and (args.json or args.trajectory or args.animate or args.gui):
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.robot import load_robot
        from rlgp_exec.timing.samples import time_plan, trajectory_dict

        model = load_robot(scene.robot.name)
        with progress.stage("timing the plan (TOPPRA, the executive's limits)"):
            timed = time_plan(plan, model, args.rate)
        traj = trajectory_dict(timed, scene.robot.name, args.planner, scene.name)
        say(f"  timed trajectory: {timed.duration_s:.1f} s, {len(timed.t)} samples at {timed.rate_hz:g} Hz")
        if args.trajectory:
            write_json(args.trajectory, traj)
            if args.trajectory != "-":
                say(f"  trajectory: {args.trajectory}")
        else:
            summary["trajectory"] = traj
        if args.animate:
            # local: per command, so `rlgp-exec --help` stays fast
            from rlgp_exec.animate import animate_plan

            with progress.stage(f"rendering the motion to {args.animate}"):
                out = animate_plan(scene, timed, args.animate, fps=args.fps, speed=args.speed)
            summary["animation"] = str(out)
            say(f"  animation: {out}")
    if args.plot:
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.planning.plot import plot_plan
        from rlgp_exec.robot import load_robot

        out = plot_plan(scene, plan, model or load_robot(scene.robot.name), args.plot)
        summary["plot"] = str(out)
        say(f"  plot (base and tool paths, actions numbered): {out}")
    write_json(args.json, summary)
    if args.gui and plan.success:
        show_plan(scene, timed)
    return EXIT_OK if plan.success else EXIT_FAILED


def cmd_show(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.scene import load_scene, randomize

    scene = load_scene(scene_arg(args.scene))  # before the renderer loads: a bad file is refused at once
    if args.seed:  # seed 0 is the file as written, as in `bench`
        scene = randomize(scene, args.seed)
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.world.render import render_scene_png

    with stage(f"rendering {scene.name} ({args.view} view)"):
        out = render_scene_png(scene, args.png, width=args.width, height=args.height, view=args.view)
    say(f"{scene.name}: wrote {out}")
    return 0


def add_plan_commands(sub: Any) -> None:
    """The ``plan`` and ``show`` subcommands."""
    s = command(sub, "plan", "plan a scene's task (validated by replay in PyBullet)", """
        rlgp-exec plan sorting_hsr
        rlgp-exec plan my_scene.toml --planner gnpp --time-budget 60
        rlgp-exec plan sorting_hsr --plot plan.png --animate plan.gif
        rlgp-exec plan sorting_hsr --json - | jq .trajectory.duration_s
    """)
    s.add_argument("scene", help=SCENE_HELP)
    planner_flag(s)
    s.add_argument("--seed", type=int, help="randomise object poses with this seed (0: the file as is, as in bench)")
    json_flag(s, "the plan's summary and its timed trajectory (docs/trajectory.schema.json)")
    s.add_argument("--trajectory", metavar="FILE",
                   help="write the timed trajectory to FILE instead of into --json ('-': stdout)")
    s.add_argument("--rate", type=float, default=10.0, help="[Hz] the timed trajectory's sample rate")
    s.add_argument("--plot", metavar="PNG",
                   help="write a top view: base and tool paths, each action's place numbered and listed")
    animate_flags(s, "the planned motion")
    gui_flag(s, "the planned motion")
    limit_flags(s)
    s.set_defaults(func=cmd_plan)

    s = command(sub, "show", "render a scene to a PNG (PyBullet camera)", """
        rlgp-exec show sorting_hsr --png scene.png
        rlgp-exec show my_scene.toml --png top.png --view top --seed 3
    """)
    s.add_argument("scene", help=SCENE_HELP)
    s.add_argument("--png", required=True, help="the PNG to write")
    s.add_argument("--seed", type=int, help="randomise object poses with this seed (0: the file as is, as in bench)")
    s.add_argument("--view", choices=["overview", "top", "robot"], default="overview",
                   help="the camera: an overview, from above, or the robot's head camera")
    s.add_argument("--width", type=int, default=960, help="[px]")
    s.add_argument("--height", type=int, default=720, help="[px]")
    s.set_defaults(func=cmd_show)
