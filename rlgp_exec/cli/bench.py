"""``bench``: the named benchmarks, and a scene's planners side by side."""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

from rlgp_exec import progress
from rlgp_exec.cli.common import (
    EXIT_OK,
    plan_limits,
    progress_line,
    say,
    scene_arg,
    write_json,
)
from rlgp_exec.cli.flags import (
    command,
    json_flag,
    limit_flags,
)
from rlgp_exec.errors import RlgpError

__all__ = ["BENCHES", "add_bench_command", "cmd_bench"]


BENCHES = ("timing", "perception", "camera", "hal", "executive", "reachability", "scaling")


def cmd_bench(args: argparse.Namespace) -> int:
    scene_file = scene_arg(args.scene_file) if args.scene_file else None
    if args.task not in BENCHES and not _is_scene(args.task):
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.scene.shipped import shipped_scenes

        raise RlgpError(
            f"{args.task!r}: not a benchmark, a scene file nor a shipped scene; benchmarks: {', '.join(BENCHES)}; "
            f"or a scene (planners side by side: --planners rlgp,lgp --seeds N); shipped scenes: "
            f"{', '.join(shipped_scenes())}"
        )
    if args.task not in BENCHES:
        scene_arg(args.task)  # a missing .toml file: the resolver's error names it
    if args.task == "scaling":
        return _bench_scaling(args)
    with progress.stage(f"bench {args.task}" + (f" on {scene_file.name}" if scene_file else "")):
        result = _bench(args, scene_file)
    write_json(args.json, result)
    for k, v in result.get("summary", {}).items():
        if isinstance(v, dict):
            for k2, v2 in v.items():
                say(f"{k}.{k2}: {v2}")
        else:
            say(f"{k:40s} {v}")
    return EXIT_OK


def _bench(args: argparse.Namespace, scene_file: Path | None) -> dict[str, Any]:
    task = args.task
    if task == "timing":
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.timing import run_timing_bench

        result = run_timing_bench(seed=args.seed or 0)
    elif task == "perception":
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.perception import run_perception_bench

        result = run_perception_bench(seed=args.seed or 0)
    elif task == "reachability":
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.reach import run_reachability_bench

        if scene_file is None:
            raise RlgpError("bench reachability needs a scene: rlgp-exec bench reachability SCENE [--samples N]")
        result = run_reachability_bench(scene_file, samples=args.samples, seed=args.seed or 0, workers=args.workers)
    elif task == "camera":
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.camera import SCENE, run_camera_bench

        result = run_camera_bench(scene_file or SCENE, seed=args.seed or 0)
    elif task == "hal":
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.hal import run_hal_bench

        result = run_hal_bench()
    elif task == "executive":
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.executive import run_executive_bench
        from rlgp_exec.demo import scene_path

        task_scene = scene_file or scene_path("sorting_hsr")
        result = run_executive_bench(task_scene, task_scene, n_faults=args.faults, seed=args.seed or 0)
    else:  # a scene (cmd_bench checked): its planners side by side
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.bench.planners import run_planner_bench

        planners = (args.planners or "rlgp,lgp").split(",")
        result = run_planner_bench(
            scene_arg(task), planners, args.seeds or 20, workers=args.workers, cluster=args.cluster, plot=args.plot,
            limits=plan_limits(args),
        )
    return result


def _is_scene(arg: str) -> bool:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.scene.shipped import resolve_scene

    try:
        resolve_scene(arg)
    except RlgpError:
        return Path(arg).suffix == ".toml"  # a missing scene file: the resolver's error names it
    return True


def _bench_scaling(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.bench.scaling import parse_counts, run_scaling_bench

    def progress(rec: dict, done: int, total: int) -> None:
        spent = rec["cpu_s"] if rec["cpu_s"] is not None else rec["wall_s"]
        why = "" if rec["success"] else rec["reason"][:100]
        progress_line(
            f"[{done:3d}/{total}] {rec['robot']} N={rec['N']:2d} seed {rec['seed']:2d} {rec['planner']:5s} "
            f"{'ok  ' if rec['success'] else 'FAIL'} {spent:7.2f} s CPU {rec['wall_s']:7.2f} s wall {why}"
        )

    result = run_scaling_bench(
        robots=args.robots.split(","), counts=parse_counts(args.n), seeds=args.seeds or 10,
        planners=(args.planners or "rlgp,gnpp").split(","), limits=plan_limits(args), plot=args.plot, on_run=progress,
    )
    write_json(args.json, result)
    say(f"{'planner':8s} {'N':>3s} {'success':>8s} {'median CPU s (ok)':>18s} {'median CPU s (all)':>19s}")
    for p, by_n in result["summary"].items():
        for n, cell in by_n.items():
            ok_t, all_t = cell["time_s_median"], cell["time_s_median_all"]
            say(f"{p:8s} {n:>3s} {cell['successes']:3d}/{cell['runs']:<4d} "
                f"{'-' if ok_t is None else f'{ok_t:.2f}':>18s} {'-' if all_t is None else f'{all_t:.2f}':>19s}")
    if args.plot:
        say(f"plot: {result['plot']}")
    return 0


def add_bench_command(sub: Any) -> None:
    """The ``bench`` subcommand."""
    s = command(sub, "bench", "benchmarks: timing, perception, hal, reachability, executive, scaling, planners", """
        rlgp-exec bench timing
        rlgp-exec bench executive --faults 10 --json bench.json
        rlgp-exec bench reachability sorting_hsr --samples 400
        rlgp-exec bench sorting_hsr --planners rlgp,lgp --seeds 10 --plot paths.png
        rlgp-exec bench scaling --robots hsr --n 2,5 --seeds 3
    """)
    s.add_argument(
        "task", help="timing | perception | camera | reachability | hal | executive | scaling | a scene (file or "
        "shipped name): its planners side by side"
    )
    s.add_argument("scene_file", nargs="?", metavar="SCENE",
                   help="the scene, for `bench reachability` (and `bench camera`, `bench executive`)")
    s.add_argument("--samples", type=int, default=200, help="reachability graph nodes")
    s.add_argument("--faults", type=int, default=50, help="bench executive: faults to inject")
    s.add_argument("--planners", help="comma-separated (scene default: rlgp,lgp; scaling: rlgp,gnpp)")
    s.add_argument("--seeds", type=int, help="seeds per scene (scene default 20; scaling: per robot and N, 10)")
    s.add_argument("--robots", default="pr2,hsr", help="scaling: the robots, comma-separated")
    s.add_argument("--n", default="2..10", help="scaling: object counts, a range A..B or a list A,B,C")
    s.add_argument("--seed", type=int, help="the benchmark's seed (default 0)")
    s.add_argument(
        "--workers", type=int, default=None,
        help="worker processes (reachability: default all cores; planners: default 1, seeds run in sequence)",
    )
    s.add_argument("--cluster", help="planners: a Dask scheduler address (tcp://host:8786) to run the sweep on")
    s.add_argument(
        "--plot", metavar="PNG",
        help="planners: the base trajectories (top view, one panel per planner); scaling: time and success "
        "against N; to this PNG",
    )
    json_flag(s, "the benchmark's records and summary")
    limit_flags(s)
    s.set_defaults(func=cmd_bench)
