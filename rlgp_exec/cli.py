"""``rlgp-exec``: the command line (the contract of DESIGN.md).

Library code logs; this module is the only place that prints. Every subcommand returns an exit
code: 0 success, 1 the task failed (e.g. no plan), 2 bad input or a feature that has not landed.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rlgp_exec.errors import RlgpError

if TYPE_CHECKING:
    from rlgp_exec.planning.limits import PlanLimits

__all__ = ["main"]

log = logging.getLogger("rlgp_exec")
PROGRESS_LOGGERS = (  # candidates, long sequences' keyframe chunks, GNPP iterations
    "rlgp_exec.planning.rlgp", "rlgp_exec.planning.nlp.keyframe_chunks", "rlgp_exec.planning.gnpp.planner",
)


_progress: list[logging.Handler] = []  # the handler _show_progress attached, for the next main() to replace


def _show_progress(on: bool) -> None:
    """What long planning is doing (R-LGP's candidates, GNPP's iterations) on stderr, one line each:
    the planners' INFO lines, without the root handler's copy. stdout stays the command's own."""
    for name in PROGRESS_LOGGERS:
        lg = logging.getLogger(name)
        for h in _progress:
            lg.removeHandler(h)
        lg.propagate = True
        lg.setLevel(logging.NOTSET)
    _progress.clear()
    if not on:
        return
    handler = logging.StreamHandler(sys.stderr)
    handler.setFormatter(logging.Formatter("  .. %(message)s"))
    _progress.append(handler)
    for name in PROGRESS_LOGGERS:
        lg = logging.getLogger(name)
        lg.addHandler(handler)
        lg.setLevel(min(logging.getLogger().getEffectiveLevel(), logging.INFO))
        lg.propagate = False


def _limits(args: argparse.Namespace) -> PlanLimits:
    """``--time-budget``/``--max-expansions`` as the planners' limits (bad values: RlgpError, exit 2)."""
    from rlgp_exec.planning.limits import PlanLimits

    return PlanLimits(args.time_budget, args.max_expansions)


def _write_json(path: str | None, data: dict[str, Any]) -> None:
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(data, indent=2, default=float) + "\n")


# ---------------------------------------------------------------------------------- show
def cmd_show(args: argparse.Namespace) -> int:
    from rlgp_exec.scene import load_scene, randomize

    scene = load_scene(args.scene)  # before the renderer loads: a bad file is refused at once
    if args.seed:  # seed 0 is the file as written, as in `bench`
        scene = randomize(scene, args.seed)
    from sim.render import render_scene_png

    out = render_scene_png(scene, args.png, width=args.width, height=args.height, view=args.view)
    print(f"{scene.name}: wrote {out}")
    return 0


# ---------------------------------------------------------------------------------- bench
def cmd_bench(args: argparse.Namespace) -> int:
    task = args.task
    if task == "timing":
        from rlgp_exec.timing.bench import run_timing_bench

        result = run_timing_bench(seed=args.seed or 0)
    elif task == "perception":
        from perception.bench import run_perception_bench

        result = run_perception_bench(seed=args.seed or 0)
    elif task == "reachability":
        from rlgp_exec.reach.bench import run_reachability_bench

        if not args.scene_file:
            raise RlgpError("bench reachability needs a scene: rlgp-exec bench reachability SCENE [--samples N]")
        result = run_reachability_bench(
            args.scene_file, samples=args.samples, seed=args.seed or 0, workers=args.workers
        )
    elif task == "camera":
        from rlgp_exec.executive.camera_bench import SCENE, run_camera_bench

        result = run_camera_bench(Path(args.scene_file) if args.scene_file else SCENE, seed=args.seed or 0)
    elif task == "hal":
        from rlgp_exec.hal.bench import run_hal_bench

        result = run_hal_bench()
    elif task == "executive":
        from rlgp_exec.demo import scene_path
        from rlgp_exec.executive.bench import run_executive_bench

        task_scene = Path(args.scene_file) if args.scene_file else scene_path("sorting_hsr")
        result = run_executive_bench(task_scene, task_scene, n_faults=args.faults, seed=args.seed or 0)
    elif task == "scaling":
        return _bench_scaling(args)
    elif Path(task).suffix == ".toml":
        from rlgp_exec.planning.bench import run_planner_bench

        planners = (args.planners or "rlgp,lgp").split(",")
        result = run_planner_bench(
            task, planners, args.seeds or 20, workers=args.workers, cluster=args.cluster, plot=args.plot,
            limits=_limits(args),
        )
    else:
        print(
            f"rlgp-exec bench {task!r}: not a benchmark; valid: timing, perception, camera, hal, executive, "
            "reachability SCENE, scaling, "
            "or a scene file (planners side by side: --planners rlgp,lgp --seeds N)",
            file=sys.stderr,
        )
        return 2
    _write_json(args.json, result)
    for k, v in result.get("summary", {}).items():
        if isinstance(v, dict):
            for k2, v2 in v.items():
                print(f"{k}.{k2}: {v2}")
        else:
            print(f"{k:40s} {v}")
    return 0


def _bench_scaling(args: argparse.Namespace) -> int:
    from rlgp_exec.planning.scaling_bench import parse_counts, run_scaling_bench

    def progress(rec: dict, done: int, total: int) -> None:
        spent = rec["cpu_s"] if rec["cpu_s"] is not None else rec["wall_s"]
        why = "" if rec["success"] else rec["reason"][:100]
        print(f"  [{done:3d}/{total}] {rec['robot']} N={rec['N']:2d} seed {rec['seed']:2d} {rec['planner']:5s} "
              f"{'ok  ' if rec['success'] else 'FAIL'} {spent:7.2f} s CPU {rec['wall_s']:7.2f} s wall {why}",
              file=sys.stderr, flush=True)

    result = run_scaling_bench(
        robots=args.robots.split(","), counts=parse_counts(args.n), seeds=args.seeds or 10,
        planners=(args.planners or "rlgp,gnpp").split(","), limits=_limits(args), plot=args.plot, on_run=progress,
    )
    _write_json(args.json, result)
    print(f"{'planner':8s} {'N':>3s} {'success':>8s} {'median CPU s (ok)':>18s} {'median CPU s (all)':>19s}")
    for p, by_n in result["summary"].items():
        for n, cell in by_n.items():
            ok_t, all_t = cell["time_s_median"], cell["time_s_median_all"]
            print(f"{p:8s} {n:>3s} {cell['successes']:3d}/{cell['runs']:<4d} "
                  f"{'-' if ok_t is None else f'{ok_t:.2f}':>18s} {'-' if all_t is None else f'{all_t:.2f}':>19s}")
    if args.plot:
        print(f"plot: {result['plot']}")
    return 0


# ---------------------------------------------------------------------------------- sim-robot
def cmd_sim_robot(args: argparse.Namespace) -> int:
    from sim.robot_server import main as server_main

    argv = ["--robot", args.robot, "--transport", args.transport]
    for flag, value in (
        ("--scene", args.scene),
        ("--endpoint", args.endpoint),
        ("--namespace", args.namespace),
        ("--zenoh-config", args.zenoh_config),
    ):
        if value:
            argv += [flag, value]
    if not args.camera:
        return server_main(argv)
    import subprocess

    from rlgp_exec.hal.zenoh_keys import DEFAULT_ENDPOINT
    from sim.robot_process import camera_command

    if args.transport != "zenoh" or not args.scene:
        raise RlgpError("sim-robot --camera publishes over zenoh and renders a scene: give --transport zenoh --scene")
    # the camera node waits for the server's endpoint, so it can start first
    cam = subprocess.Popen(camera_command(args.robot, args.scene, args.endpoint or DEFAULT_ENDPOINT,
                                          args.namespace or "", args.camera_jpeg))
    try:
        return server_main(argv)
    finally:
        cam.terminate()
        cam.wait(10)


# ---------------------------------------------------------------------------------- plan
def cmd_plan(args: argparse.Namespace) -> int:
    from rlgp_exec.scene import load_scene, randomize

    _limits(args)  # bad limits are refused before the scene loads
    scene = load_scene(args.scene)  # before the planners load: a bad file is refused at once
    if args.seed:  # seed 0 is the file as written, as in `bench`
        scene = randomize(scene, args.seed)
    from rlgp_exec.planning.registry import plan as run_planner

    plan = run_planner(scene, args.planner, seed=args.seed or 0, limits=_limits(args))
    summary = plan.summary()
    print(
        f"{scene.name}: {args.planner} {'found a valid plan' if plan.success else 'failed'} in "
        f"{plan.planning_time_s:.2f} s ({plan.n_nlp} NLPs, {plan.nodes_expanded} nodes expanded)"
    )
    for a in plan.actions:
        print(f"  {a}")
    if plan.success:
        print(f"  base path {plan.base_path_length_m:.2f} m; replay: collision-free, goal met")
    else:
        print(f"  reason: {plan.reason}")
    if args.plot:
        import numpy as np

        from rlgp_exec.planning.plot import plot_base_paths

        xy = [np.concatenate([ph.path[:, :2] for ph in plan.phases if len(ph.path)])] if plan.success else []
        out = plot_base_paths(scene, {args.planner: xy}, args.plot, f"{scene.name}: {args.planner} base path")
        summary["plot"] = str(out)
        print(f"  base path plot: {out}")
    _write_json(args.json, summary)
    return 0 if plan.success else 1


# ---------------------------------------------------------------------------------- run / replay
def cmd_run(args: argparse.Namespace) -> int:
    from rlgp_exec.executive.runner import RunOptions, run_task
    from rlgp_exec.scene import load_scene

    _limits(args)  # bad limits are refused before the scene loads
    scene = load_scene(args.scene)
    if args.perceive:
        if args.backend != "sim":
            raise RlgpError("--perceive renders the head camera in simulation: use it with --backend sim")
        from perception.runner import perceive_scene

        res = perceive_scene(scene)
        if res.missing:
            raise RlgpError(f"perception did not find {sorted(res.missing)}")
        scene = res.scene
    opts = RunOptions(
        backend=args.backend,
        planner=args.planner,
        record=Path(args.record) if args.record else None,
        endpoint=args.endpoint,
        namespace=args.namespace,
        zenoh_config=_zenoh_config(args),
        seed=args.seed,
        objects=args.objects,
        limits=_limits(args),
        foxglove=args.foxglove,
    )
    _print_live_view(args.foxglove)
    result, _ = run_task(scene, opts, args.goal)
    print(f"{scene.name}: {result.status.value}: {result.detail}")
    if result.actions:
        print("  plan: " + " ".join(result.actions))
    if result.executed != result.actions:  # a replan, or a task that stopped part-way
        print("  executed: " + (" ".join(result.executed) or "nothing"))
    print(
        f"  planning {result.planning_time_s:.2f} s ({result.plans} plan(s), {result.replans} replan(s)); "
        f"execution {result.execution_time_s:.1f} s; base travelled {result.base_distance_m:.2f} m"
    )
    if args.record:
        print(f"  recorded {args.record}")
    _write_json(args.json, result.as_dict())
    return 0 if result.ok else 1


def cmd_replay(args: argparse.Namespace) -> int:
    from rlgp_exec.executive.replay import replay

    report = replay(args.file, png=args.png)  # a bad recording: a RecordingError, exit 2 (main)
    print(report.text())
    _write_json(
        args.json,
        {"complete": report.complete, "ending": report.ending, "truncated_at": report.truncated_at,
         "messages": report.messages, "states": report.states,
         "duration_s": report.duration_s, "base_distance_m": report.base_distance_m,
         "transitions": list(report.transitions), "results": list(report.results),
         "collisions": list(report.collisions)},
    )
    return 0 if not report.collisions else 1


def _zenoh_config(args: argparse.Namespace) -> Path | None:
    """--zenoh-config (default: $ZENOH_CONFIG); read (and an unreadable one named) by session_config."""
    return Path(args.zenoh_config) if args.zenoh_config else None


_DAEMON_SETTINGS = ("robot", "backend", "scene", "endpoint", "listen", "namespace", "record_dir", "planner",
                    "objects", "time_budget", "max_expansions", "zenoh_config")


def _daemon_config_flags(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--config", metavar="TOML",
        help="the daemon's settings as a TOML file (see docs/daemon.example.toml); options given override it",
    )
    # not given -> None, so that the file's value applies (defaults: DaemonConfig's)
    s.set_defaults(robot=None, backend=None, namespace=None, planner=None, zenoh_config=None)


def _daemon_settings(args: argparse.Namespace) -> argparse.Namespace:
    """``args`` with --config's settings where an option was not given (bad ones: RlgpError, exit 2)."""
    from dataclasses import replace

    from rlgp_exec.executive.daemon_config import DaemonConfig, load_daemon_config

    cfg = load_daemon_config(args.config) if args.config else DaemonConfig()
    cfg = cfg.merged({k: getattr(args, k) for k in _DAEMON_SETTINGS})
    if cfg.zenoh_config is None and os.environ.get("ZENOH_CONFIG"):
        cfg = replace(cfg, zenoh_config=Path(os.environ["ZENOH_CONFIG"]))
    if cfg.scene is None:
        raise RlgpError("daemon: no scene: give --scene FILE, or scene = \"FILE\" in --config")
    values = {k: str(v) if isinstance(v, Path) else v for k, v in vars(cfg).items()}
    return argparse.Namespace(**{**vars(args), **values})


def cmd_daemon(args: argparse.Namespace) -> int:
    import signal
    import threading

    from rlgp_exec.executive.daemon import DEFAULT_LISTEN, Daemon, DaemonOptions
    from rlgp_exec.executive.runner import RunOptions
    from rlgp_exec.scene import load_scene

    args = _daemon_settings(args)
    limits = _limits(args)
    scene = load_scene(args.scene)
    if scene.robot.name != args.robot:
        raise RlgpError(f"--scene {args.scene} is for robot {scene.robot.name!r}, not --robot {args.robot!r}")
    config = _zenoh_config(args)
    daemon = Daemon(
        scene,
        RunOptions(
            backend=args.backend,
            planner=args.planner,
            endpoint=args.endpoint,
            namespace=args.namespace,
            zenoh_config=config if args.backend == "zenoh" else None,
            objects=args.objects,
            limits=limits,
        ),
        DaemonOptions(
            args.listen or (None if config else DEFAULT_LISTEN),
            args.namespace,
            Path(args.record_dir) if args.record_dir else None,
            config,
        ),
    )
    done = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: done.set())
    daemon.start()  # on failure it has closed what it opened; main() prints the one line and exits 2
    where = daemon.opts.listen or config
    print(f"daemon ready: {args.robot} via {args.backend}; requests at {daemon.base}/* on {where}", flush=True)
    try:
        while not done.wait(0.2) and not daemon.dead.is_set():
            pass
    finally:
        daemon.stop()
    if daemon.fatal is not None:
        print(f"daemon: {daemon.fatal}", file=sys.stderr)
        return 1
    return 0


def cmd_request(args: argparse.Namespace) -> int:
    import time

    from rlgp_exec.executive.daemon import DEFAULT_LISTEN, request

    config = _zenoh_config(args)
    endpoint = args.endpoint or (None if config else DEFAULT_LISTEN)
    payload = {"literals": args.literals} if args.what == "goal" else None
    reply = request(endpoint, args.what, payload, args.namespace, zenoh_config=config)
    print(json.dumps(reply, indent=2))
    if args.what == "goal" and args.wait and reply.get("ok"):
        task = reply["task"]
        while True:
            time.sleep(0.5)
            st = request(endpoint, "status", None, args.namespace, zenoh_config=config)
            last = st.get("last") or {}
            if last.get("task") == task:
                print(json.dumps(last, indent=2))
                return 0 if last.get("status") == "succeeded" else 1
            if not st.get("ok"):
                print(json.dumps(st, indent=2))
                return 1
    return 0 if reply.get("ok") else 1


# ---------------------------------------------------------------------------------- rg
def cmd_rg(args: argparse.Namespace) -> int:
    import copy

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

    scene = load_scene(args.scene)
    model = load_robot(scene.robot.name)
    graph, stats = load_or_build(scene, params=RGParams(samples=args.samples))
    print(
        f"{scene.name}: {graph.G.number_of_nodes()} nodes, {graph.G.number_of_edges()} edges "
        f"({'loaded from cache' if stats.from_cache else f'built in {stats.build_time_s:.2f} s'})"
    )
    before, before_graph = GraphSnapshot(graph), copy.deepcopy(graph)
    checker = WorldChecker(scene, model.manipulator().group)
    planner = ReachabilityPlanner(graph, ReachIK(model, scene, nominal_q(model, scene)), checker, rng_seed=1)
    rng = np.random.default_rng(1)
    lo, hi = graph.X[graph.alive].min(axis=0), graph.X[graph.alive].max(axis=0)
    shown, ok = None, 0
    for _ in range(args.queries):
        res = planner.query(rng.uniform(lo, hi), rng.uniform(lo, hi))
        ok += res.ok
        if res.ok and (shown is None or len(res.path) > len(shown)):
            shown = res.path
    path_x = None
    if shown is not None:
        tool = model.manipulator().tool_frame
        path_x = np.array([model.fk(q, tool)[:3, 3] for q in shown])
    print(
        f"{args.queries} random queries: {ok} answered; graph now {graph.G.number_of_nodes()} nodes; {planner.counters}"
    )
    if args.png:
        print(f"wrote {draw_graph_png(graph, scene, args.png, before, path_x, before_graph)}")
    checker.close()
    return 0


# ---------------------------------------------------------------------------------- perceive
def cmd_perceive(args: argparse.Namespace) -> int:
    if args.image:
        import numpy as np

        from perception.camera import CameraIntrinsics
        from perception.runner import perceive_image

        if not args.intrinsics:
            raise RlgpError("--image needs --intrinsics W,H,fx,fy,cx,cy (and --tag-size)")
        tags = perceive_image(args.image, CameraIntrinsics.parse(args.intrinsics), args.tag_size, args.detector)
        for t in tags:
            pos = (
                "-" if not t.get("T_camera_tag") else " ".join(f"{v:+.4f}" for v in np.array(t["T_camera_tag"])[:3, 3])
            )
            print(f"tag {t['tag_id']:4d}  {'ok' if t['ok'] else 'rejected':8s}  t_camera_tag [m] {pos}  {t['reason']}")
        if not tags:
            print("no tags found")
        _write_json(args.json, {"image": args.image, "tags": tags})
        return 0
    if not args.scene:
        raise RlgpError("give a SCENE file, or --image FILE --intrinsics W,H,fx,fy,cx,cy")
    if args.plan:
        return _perceive_and_plan(args)
    from perception.runner import perceive_scene
    from rlgp_exec.scene import load_scene

    scene = load_scene(args.scene)
    res = perceive_scene(scene, perturb_m=args.perturb, seed=args.seed, noise_std=args.noise, detector=args.detector)
    print(f"{scene.name}: {res.views} camera views")
    for name in sorted(res.errors_mm):
        err, rot = res.errors_mm[name], res.yaw_errors_deg[name]
        print(f"  {name:20s} position error {err:6.2f} mm  rotation error {rot:5.2f} deg")
    for name in sorted(res.missing):
        print(f"  {name:20s} not seen")
    _write_json(
        args.json,
        {
            "scene": scene.name,
            "views": res.views,
            "pos_err_mm": res.errors_mm,
            "rot_err_deg": res.yaw_errors_deg,
            "missing": sorted(res.missing),
            "uncertain": sorted(res.uncertain),
        },
    )
    return 0 if not res.missing else 1


def _perceive_and_plan(args: argparse.Namespace) -> int:
    from rlgp_exec.perceive_plan import perceive_and_plan

    reports = perceive_and_plan(args.scene, args.plan.split(","), seed=args.seed, perturb_m=args.perturb)
    for r in reports:
        print(r.text())
    _write_json(
        args.json,
        {
            "scene": reports[0].scene,
            "perturb_m": args.perturb,
            "seed": args.seed,
            "runs": [
                {
                    "planner": r.planner,
                    "views": r.views,
                    "pos_err_mm": r.errors_mm,
                    "unseen": list(r.unseen),
                    "perceive_s": r.perceive_s,
                    **r.plan.summary(),
                    "true_world_collision_free": None if r.in_truth is None else r.in_truth.collision_free,
                    "true_world_goal_met": None if r.in_truth is None else r.in_truth.goal_met,
                    "ok": r.ok,
                }
                for r in reports
            ],
        },
    )
    return 0 if all(r.ok for r in reports) else 1


def task_script(doc: str, scene: str, planners: str, perturb_m: float = 0.03, robots: tuple[str, ...] = ()) -> int:
    """The ``tools/1x_*.py`` perception-to-plan scripts: ``perceive SCENE --plan PLANNERS`` on a shipped
    scene with that script's defaults. ``scene`` may hold ``{robot}`` when ``robots`` lists the choices."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0])
    ap.add_argument("--planners", default=planners)
    if robots:
        ap.add_argument("--robot", choices=robots, default=robots[0])
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--perturb", type=float, default=perturb_m, help="[m] how far the objects are from the file")
    ap.add_argument("--json")
    args = ap.parse_args()
    from rlgp_exec.demo import scene_path

    path = scene_path(scene.format(robot=getattr(args, "robot", "")))
    argv = ["perceive", str(path), "--plan", args.planners, "--seed", str(args.seed), "--perturb", str(args.perturb)]
    return main(argv + (["--json", args.json] if args.json else []))


# ---------------------------------------------------------------------------------- demo
def cmd_demo(args: argparse.Namespace) -> int:
    from rlgp_exec.demo import DEMO_SCENE, DEMO_SCENES, run_demo

    scene = args.scene or DEMO_SCENE
    if scene not in DEMO_SCENES:
        print(f"rlgp-exec demo: unknown scene {scene!r}; valid: {list(DEMO_SCENES)}", file=sys.stderr)
        return 2
    _print_live_view(args.foxglove)
    report = run_demo(Path(args.out), seed=args.seed, scene_name=scene, foxglove=args.foxglove)
    print(report.text())
    return 0 if report.ok else 1


def _port(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (1..65535)")
    return int(text)


def _foxglove_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--foxglove", nargs="?", type=_port, const=8765, default=None, metavar="PORT",
        help="serve the run live to Foxglove (robot, TF, scene, plan) on ws://127.0.0.1:PORT (default 8765)",
    )


def _print_live_view(port: int | None) -> None:
    if port is not None:
        print(f"live view: open Foxglove, connect to ws://127.0.0.1:{port}", flush=True)


def _zenoh_config_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--zenoh-config",
        default=os.environ.get("ZENOH_CONFIG"),
        help="zenoh: a json5 configuration (TLS certificates, access control; default $ZENOH_CONFIG); "
        "an endpoint flag replaces its listen/connect endpoints",
    )


def _limit_flags(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--time-budget", type=float, metavar="SECONDS",
        help="CPU time [s] a planning call may spend (> 0; default: the planner's own)",
    )
    s.add_argument(
        "--max-expansions", type=int, metavar="N",
        help="symbolic search expansions (R-LGP's search; GNPP's logic search per iteration; "
        "default: the planner's own)",
    )


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="rlgp-exec", description="Sense-plan-act executive for mobile manipulators.")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)")
    ap.add_argument(
        "-q", "--quiet", action="store_true", help="no planning progress on stderr (candidates, iterations)"
    )
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = sub.add_parser("plan", help="plan a scene's task")
    s.add_argument("scene")
    s.add_argument(
        "--planner",
        default="rlgp",
        help="rlgp: reachability-graph heuristic; lgp: distance-only baseline; gnpp and its ablations "
        "(unknown names list the valid ones)",
    )
    s.add_argument("--seed", type=int, help="randomise object poses with this seed (0: the file as is, as in bench)")
    s.add_argument("--json")
    s.add_argument("--plot", help="write the plan's base path (top view of the scene) to this PNG")
    _limit_flags(s)
    s.set_defaults(func=cmd_plan)

    s = sub.add_parser("run", help="plan and execute a scene's task through a HAL backend")
    s.add_argument("scene")
    s.add_argument("--backend", choices=["sim", "zenoh", "can"], default="sim")
    s.add_argument("--perceive", action="store_true", help="(sim) initial object poses from AprilTag perception")
    s.add_argument("--record", help="write the run to this MCAP file")
    _foxglove_flag(s)
    s.add_argument("--planner", default="rlgp")
    s.add_argument("--goal", action="append", help="a goal literal, e.g. '(on block tray)' (repeatable)")
    s.add_argument("--endpoint", help="zenoh: the robot's endpoint, e.g. tcp/127.0.0.1:7447")
    s.add_argument("--namespace", default="", help="zenoh: key prefix")
    _zenoh_config_flag(s)
    s.add_argument("--seed", type=int, default=0)
    s.add_argument(
        "--objects", choices=["camera", "mocap", "file"],
        help="where object poses come from (default: zenoh camera, sim its truth, can the file)",
    )
    s.add_argument("--json")
    _limit_flags(s)
    s.set_defaults(func=cmd_run)

    s = sub.add_parser("bench", help="benchmarks: timing, perception, hal, reachability, executive, scaling, planners")
    s.add_argument(
        "task", help="timing | perception | camera | reachability | hal | executive | scaling | a scene file"
    )
    s.add_argument("scene_file", nargs="?", help="the scene, for `bench reachability` (and `bench camera`)")
    s.add_argument("--samples", type=int, default=200, help="reachability graph nodes")
    s.add_argument("--faults", type=int, default=50, help="bench executive: faults to inject")
    s.add_argument("--planners", help="comma-separated (scene file default: rlgp,lgp; scaling: rlgp,gnpp)")
    s.add_argument("--seeds", type=int, help="seeds per scene (scene file default 20; scaling: per robot and N, 10)")
    s.add_argument("--robots", default="pr2,hsr", help="scaling: the robots, comma-separated")
    s.add_argument("--n", default="2..10", help="scaling: object counts, a range A..B or a list A,B,C")
    s.add_argument("--seed", type=int)
    s.add_argument(
        "--workers", type=int, default=None,
        help="worker processes (reachability: default all cores; planners: default 1, seeds run in sequence)",
    )
    s.add_argument("--cluster", help="planners: a Dask scheduler address (tcp://host:8786) to run the sweep on")
    s.add_argument(
        "--plot",
        help="planners: the base trajectories (top view, one panel per planner); scaling: time and success "
        "against N; to this PNG",
    )
    s.add_argument("--json")
    _limit_flags(s)
    s.set_defaults(func=cmd_bench)

    s = sub.add_parser("perceive", help="detect AprilTags in rendered or given images")
    s.add_argument("scene", nargs="?", help="a scene: look around for its tagged objects in simulation")
    s.add_argument("--image", help="an image file (PNG/JPEG) from a real camera instead of a scene")
    s.add_argument("--intrinsics", help="with --image: W,H,fx,fy,cx,cy [px]")
    s.add_argument("--tag-size", type=float, default=0.04, help="with --image: black-square edge [m]")
    s.add_argument("--perturb", type=float, default=0.0, help="move objects up to this far [m] from the file")
    s.add_argument("--noise", type=float, default=2.0, help="pixel noise std [grey levels]")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--detector", choices=["opencv", "pupil"], default="opencv")
    s.add_argument(
        "--plan",
        help="then plan on the perceived scene with these planners (comma-separated) and replay each plan "
        "in the true world",
    )
    s.add_argument("--json")
    s.set_defaults(func=cmd_perceive)

    s = sub.add_parser("sim-robot", help="the simulated robot server")
    s.add_argument("--robot", choices=["hsr", "pr2"], required=True)
    s.add_argument("--transport", choices=["zenoh", "can"], required=True)
    s.add_argument("--scene")
    s.add_argument("--endpoint", help="zenoh: the endpoint to listen on, e.g. tcp/127.0.0.1:7447")
    s.add_argument("--namespace", help="zenoh: key prefix, for several robots on one network")
    _zenoh_config_flag(s)
    s.add_argument("--camera", action="store_true", help="zenoh: also publish the head camera (sim.camera_node)")
    s.add_argument("--camera-jpeg", action="store_true", help="with --camera: also sensor_msgs/CompressedImage")
    s.set_defaults(func=cmd_sim_robot)

    s = sub.add_parser("daemon", help="the on-robot execution daemon (goals over Zenoh queries)")
    s.add_argument("--robot", choices=["hsr", "pr2"], default="hsr")
    s.add_argument("--backend", choices=["zenoh", "can", "sim"], default="sim")
    s.add_argument("--scene", help="the robot's environment (fixtures, objects) as a scene file")
    s.add_argument("--endpoint", help="zenoh backend: the robot's endpoint")
    s.add_argument(
        "--listen", help="where clients connect (goals, status); default tcp/127.0.0.1:7450, or the config's"
    )
    s.add_argument("--namespace", default="", help="key prefix of the daemon's (and the robot's) key space")
    s.add_argument("--record-dir", help="write one MCAP recording per task here")
    s.add_argument("--planner", default="rlgp")
    _zenoh_config_flag(s)
    s.add_argument(
        "--objects", choices=["camera", "mocap", "file"],
        help="where object poses come from (default: zenoh camera, sim its truth, can the file)",
    )
    _limit_flags(s)
    _daemon_config_flags(s)
    s.set_defaults(func=cmd_daemon)

    s = sub.add_parser(
        "request", help="ask a running daemon: goal LITERAL..., cancel, estop, rearm, reset (a FAULT), status"
    )
    s.add_argument("what", choices=["goal", "cancel", "estop", "rearm", "reset", "status"])
    s.add_argument("literals", nargs="*", help="for goal: literals such as '(on block tray)'")
    s.add_argument("--endpoint", help="the daemon's endpoint; default tcp/127.0.0.1:7450, or the config's")
    s.add_argument("--namespace", default="")
    s.add_argument("--wait", action="store_true", help="for goal: wait for the task's result")
    _zenoh_config_flag(s)
    s.set_defaults(func=cmd_request)

    s = sub.add_parser("rg", help="build/draw a scene's reachability graph")
    s.add_argument("scene")
    s.add_argument("--png", help="draw the graph before and after the queries (top and side views)")
    s.add_argument("--samples", type=int, default=200)
    s.add_argument("--queries", type=int, default=20, help="random task-space queries to run")
    s.set_defaults(func=cmd_rg)

    s = sub.add_parser("replay", help="replay an MCAP recording into PyBullet")
    s.add_argument("file")
    s.add_argument("--png", help="a picture of the final replayed state")
    s.add_argument("--json")
    s.set_defaults(func=cmd_replay)

    s = sub.add_parser("show", help="render a scene to a PNG (PyBullet camera)")
    s.add_argument("scene")
    s.add_argument("--png", required=True)
    s.add_argument("--seed", type=int, help="randomise object poses with this seed (0: the file as is, as in bench)")
    s.add_argument("--view", choices=["overview", "top", "robot"], default="overview")
    s.add_argument("--width", type=int, default=960)
    s.add_argument("--height", type=int, default=720)
    s.set_defaults(func=cmd_show)

    s = sub.add_parser("demo", help="the headless dry run behind `make demo`")
    s.add_argument("--out", default="out")
    s.add_argument("--scene", default=None, help="an HSR scene with tagged objects (default: the demo's)")
    s.add_argument("--seed", type=int, default=0, help="how the true world differs from the file")
    _foxglove_flag(s)
    s.set_defaults(func=cmd_demo)
    return ap


def main(argv: list[str] | None = None) -> int:
    # before numpy or IPOPT load OpenBLAS: one thread. The planners' matrices are small (IPOPT's KKT
    # systems, ~1000 rows): BLAS worker threads spin rather than help, and on a 2-core robot PC they take
    # the core the bench's other worker or the executive's perception needs (pick_place_pr2 level 3
    # beside another process: 0.81 -> 0.50 s, 0.60 -> 0.29 s; alone: the same). Set it to override.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    args = build_parser().parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    _show_progress(not args.quiet and args.command in ("plan", "run", "daemon", "bench"))
    try:
        return int(args.func(args))
    except RlgpError as e:
        print(f"rlgp-exec {args.command}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
