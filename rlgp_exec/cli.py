"""``rlgp-exec``: the command line (the contract of DESIGN.md).

Library code logs; this module is the only place that prints. Every subcommand returns an exit
code: 0 success, 1 the task failed (e.g. no plan), 2 bad input (a bad option, scene, goal or file).
A scene argument is a scene file or a shipped scene's name (``scene_arg``); ``-`` as a JSON output file is
stdout (the human-readable lines then go to stderr). Progress goes to stderr (``progress``).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
import sys
import time
from collections.abc import Iterator
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


#: what a command shows as it runs, beside the planners' lines: benches, the demo's stages, the executive's
#: state transitions, perception's views, animations
STAGE_LOGGERS = (
    "rlgp_exec.demo", "rlgp_exec.bench.executive", "rlgp_exec.bench.camera", "rlgp_exec.bench.hal",
    "rlgp_exec.bench.planners", "rlgp_exec.bench.scaling", "rlgp_exec.bench.timing",
    "rlgp_exec.bench.reach", "rlgp_exec.bench.perception", "rlgp_exec.animate", "rlgp_exec.gui",
    "rlgp_exec.executive.states", "rlgp_exec.executive.act",
)
EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2

_text = [sys.stdout]  # where the human-readable lines go: stderr while `--json -` has stdout


def say(*parts: object) -> None:
    """A line of the command's report (stdout, or stderr while stdout carries ``--json -``)."""
    print(*parts, file=_text[0], flush=True)


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("rlgp-exec")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def _scene(arg: str) -> Path:
    """A scene argument (file or shipped name) as a file; RlgpError (exit 2) listing the shipped names."""
    from rlgp_exec.scene.shipped import resolve_scene

    return resolve_scene(arg)


class _Planners:
    """The registry's planner names as argparse choices, read when first needed (listing them imports
    every planner package, which a command that never plans should not wait for)."""

    def __contains__(self, name: object) -> bool:
        return name in self._names()

    def __iter__(self) -> Iterator[str]:
        return iter(self._names())

    @staticmethod
    def _names() -> list[str]:
        from rlgp_exec.planning.registry import planner_names

        return planner_names()


PLANNER_CHOICES = _Planners()


def _limits(args: argparse.Namespace) -> PlanLimits:
    """``--time-budget``/``--max-expansions`` as the planners' limits (bad values: RlgpError, exit 2)."""
    from rlgp_exec.planning.limits import PlanLimits

    return PlanLimits(args.time_budget, args.max_expansions)


def _write_json(path: str | None, data: dict[str, Any]) -> None:
    """``data`` as JSON to ``path``; ``-`` is stdout; None writes nothing."""
    if not path:
        return
    text = json.dumps(data, indent=2, default=float) + "\n"
    if path == "-":
        sys.stdout.write(text)
        sys.stdout.flush()
        return
    try:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(text)
    except OSError as e:
        raise RlgpError(f"cannot write {path}: {e.strerror or e}") from e


# ---------------------------------------------------------------------------------- show
def cmd_show(args: argparse.Namespace) -> int:
    from rlgp_exec.scene import load_scene, randomize

    scene = load_scene(_scene(args.scene))  # before the renderer loads: a bad file is refused at once
    if args.seed:  # seed 0 is the file as written, as in `bench`
        scene = randomize(scene, args.seed)
    from rlgp_exec.progress import stage
    from rlgp_exec.world.render import render_scene_png

    with stage(f"rendering {scene.name} ({args.view} view)"):
        out = render_scene_png(scene, args.png, width=args.width, height=args.height, view=args.view)
    say(f"{scene.name}: wrote {out}")
    return 0


# ---------------------------------------------------------------------------------- bench
BENCHES = ("timing", "perception", "camera", "hal", "executive", "reachability", "scaling")


def cmd_bench(args: argparse.Namespace) -> int:
    from rlgp_exec import progress

    scene_file = _scene(args.scene_file) if args.scene_file else None
    if args.task not in BENCHES and not _is_scene(args.task):
        from rlgp_exec.scene.shipped import shipped_scenes

        raise RlgpError(
            f"{args.task!r}: not a benchmark, a scene file nor a shipped scene; benchmarks: {', '.join(BENCHES)}; "
            f"or a scene (planners side by side: --planners rlgp,lgp --seeds N); shipped scenes: "
            f"{', '.join(shipped_scenes())}"
        )
    if args.task not in BENCHES:
        _scene(args.task)  # a missing .toml file: the resolver's error names it
    if args.task == "scaling":
        return _bench_scaling(args)
    with progress.stage(f"bench {args.task}" + (f" on {scene_file.name}" if scene_file else "")):
        result = _bench(args, scene_file)
    _write_json(args.json, result)
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
        from rlgp_exec.bench.timing import run_timing_bench

        result = run_timing_bench(seed=args.seed or 0)
    elif task == "perception":
        from rlgp_exec.bench.perception import run_perception_bench

        result = run_perception_bench(seed=args.seed or 0)
    elif task == "reachability":
        from rlgp_exec.bench.reach import run_reachability_bench

        if scene_file is None:
            raise RlgpError("bench reachability needs a scene: rlgp-exec bench reachability SCENE [--samples N]")
        result = run_reachability_bench(scene_file, samples=args.samples, seed=args.seed or 0, workers=args.workers)
    elif task == "camera":
        from rlgp_exec.bench.camera import SCENE, run_camera_bench

        result = run_camera_bench(scene_file or SCENE, seed=args.seed or 0)
    elif task == "hal":
        from rlgp_exec.bench.hal import run_hal_bench

        result = run_hal_bench()
    elif task == "executive":
        from rlgp_exec.bench.executive import run_executive_bench
        from rlgp_exec.demo import scene_path

        task_scene = scene_file or scene_path("sorting_hsr")
        result = run_executive_bench(task_scene, task_scene, n_faults=args.faults, seed=args.seed or 0)
    else:  # a scene (cmd_bench checked): its planners side by side
        from rlgp_exec.bench.planners import run_planner_bench

        planners = (args.planners or "rlgp,lgp").split(",")
        result = run_planner_bench(
            _scene(task), planners, args.seeds or 20, workers=args.workers, cluster=args.cluster, plot=args.plot,
            limits=_limits(args),
        )
    return result


def _is_scene(arg: str) -> bool:
    from rlgp_exec.scene.shipped import resolve_scene

    try:
        resolve_scene(arg)
    except RlgpError:
        return Path(arg).suffix == ".toml"  # a missing scene file: the resolver's error names it
    return True


def _bench_scaling(args: argparse.Namespace) -> int:
    from rlgp_exec.bench.scaling import parse_counts, run_scaling_bench

    def progress(rec: dict, done: int, total: int) -> None:
        spent = rec["cpu_s"] if rec["cpu_s"] is not None else rec["wall_s"]
        why = "" if rec["success"] else rec["reason"][:100]
        _progress_line(
            f"[{done:3d}/{total}] {rec['robot']} N={rec['N']:2d} seed {rec['seed']:2d} {rec['planner']:5s} "
            f"{'ok  ' if rec['success'] else 'FAIL'} {spent:7.2f} s CPU {rec['wall_s']:7.2f} s wall {why}"
        )

    result = run_scaling_bench(
        robots=args.robots.split(","), counts=parse_counts(args.n), seeds=args.seeds or 10,
        planners=(args.planners or "rlgp,gnpp").split(","), limits=_limits(args), plot=args.plot, on_run=progress,
    )
    _write_json(args.json, result)
    say(f"{'planner':8s} {'N':>3s} {'success':>8s} {'median CPU s (ok)':>18s} {'median CPU s (all)':>19s}")
    for p, by_n in result["summary"].items():
        for n, cell in by_n.items():
            ok_t, all_t = cell["time_s_median"], cell["time_s_median_all"]
            say(f"{p:8s} {n:>3s} {cell['successes']:3d}/{cell['runs']:<4d} "
                f"{'-' if ok_t is None else f'{ok_t:.2f}':>18s} {'-' if all_t is None else f'{all_t:.2f}':>19s}")
    if args.plot:
        say(f"plot: {result['plot']}")
    return 0


# ---------------------------------------------------------------------------------- sim-robot
def cmd_sim_robot(args: argparse.Namespace) -> int:
    from rlgp_exec.sim.robot_server import main as server_main

    argv = ["--robot", args.robot, "--transport", args.transport]
    if args.scene:
        args.scene = str(_scene(args.scene))
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
    from rlgp_exec.sim.robot_process import camera_command

    if args.transport != "zenoh" or not args.scene:
        raise RlgpError("sim-robot --camera publishes over zenoh and renders a scene: give --transport zenoh --scene")
    # the camera node waits for the server's endpoint, so it can start first
    cam = subprocess.Popen(camera_command(args.robot, args.scene, args.endpoint or DEFAULT_ENDPOINT,
                                          args.namespace or "", args.camera_jpeg), stderr=subprocess.PIPE, text=True)
    _forward_stderr(cam)
    try:
        return server_main(argv)
    finally:
        cam.terminate()
        cam.wait(10)


def _forward_stderr(proc: Any) -> None:
    """Copy a child's stderr to ours as it comes, without PyBullet's import banner (the child is a plain
    ``python -m``: its imports are not quietened)."""
    import threading

    def pump() -> None:
        for line in proc.stderr:
            if not line.startswith("pybullet build time"):
                sys.stderr.write(line)
                sys.stderr.flush()

    threading.Thread(target=pump, name="child-stderr", daemon=True).start()


# ---------------------------------------------------------------------------------- plan
def _progress_line(msg: str) -> None:
    from rlgp_exec import progress

    d = progress.current()
    if d is not None:
        d.line(msg)


def _budget_s(planner: str, limits: PlanLimits) -> float | None:
    """The CPU budget [s] ``planner`` plans under with ``limits`` (its own default when not given)."""
    if limits.time_budget_s is not None:
        return limits.time_budget_s
    if planner in ("rlgp", "lgp"):
        from rlgp_exec.planning.rlgp import TIME_BUDGET_S

        return TIME_BUDGET_S
    try:
        from rlgp_exec.planning.gnpp import BENCH_TIMEOUT_S
    except ImportError:
        return None
    return BENCH_TIMEOUT_S if planner.startswith("gnpp") or planner == "oneway" else None


def _timing_text(cpu_s: float, budget_s: float | None, wall_s: float) -> str:
    """``X s CPU (budget Y s CPU), Z s wall``: budgets are CPU time, so times are reported in it too."""
    budget = f" (budget {budget_s:g} s CPU)" if budget_s is not None else ""
    return f"{cpu_s:.2f} s CPU{budget}, {wall_s:.2f} s wall"


def _output_checks(args: argparse.Namespace) -> None:
    """Output options refused before any work (a 3-minute plan must not end in 'cannot write')."""
    if getattr(args, "animate", None):
        from rlgp_exec.animate import check_animation_path

        check_animation_path(args.animate)
        if not (args.fps > 0 and (args.speed is None or args.speed > 0)):
            raise RlgpError(f"--fps {args.fps} and --speed {args.speed}: both must be positive")
    rate = getattr(args, "rate", None)
    if rate is not None and not (0 < rate <= 1000):
        raise RlgpError(f"--rate {rate} Hz: must lie in (0, 1000]")
    if getattr(args, "gui", False):
        from rlgp_exec.gui import require_display

        require_display()
    if getattr(args, "json", None) == "-" and getattr(args, "trajectory", None) == "-":
        raise RlgpError("--json - and --trajectory -: only one of them can have stdout")


def cmd_plan(args: argparse.Namespace) -> int:
    from rlgp_exec import progress
    from rlgp_exec.planning.budget import cpu_clock
    from rlgp_exec.scene import load_scene, randomize

    limits = _limits(args)  # bad limits are refused before the scene loads
    _output_checks(args)
    scene = load_scene(_scene(args.scene))  # before the planners load: a bad file is refused at once
    if args.seed:  # seed 0 is the file as written, as in `bench`
        scene = randomize(scene, args.seed)
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
        from rlgp_exec.robot import load_robot
        from rlgp_exec.timing.samples import time_plan, trajectory_dict

        model = load_robot(scene.robot.name)
        with progress.stage("timing the plan (TOPPRA, the executive's limits)"):
            timed = time_plan(plan, model, args.rate)
        traj = trajectory_dict(timed, scene.robot.name, args.planner, scene.name)
        say(f"  timed trajectory: {timed.duration_s:.1f} s, {len(timed.t)} samples at {timed.rate_hz:g} Hz")
        if args.trajectory:
            _write_json(args.trajectory, traj)
            if args.trajectory != "-":
                say(f"  trajectory: {args.trajectory}")
        else:
            summary["trajectory"] = traj
        if args.animate:
            from rlgp_exec.animate import animate_plan

            with progress.stage(f"rendering the motion to {args.animate}"):
                out = animate_plan(scene, timed, args.animate, fps=args.fps, speed=args.speed)
            summary["animation"] = str(out)
            say(f"  animation: {out}")
    if args.plot:
        from rlgp_exec.planning.plot import plot_plan
        from rlgp_exec.robot import load_robot

        out = plot_plan(scene, plan, model or load_robot(scene.robot.name), args.plot)
        summary["plot"] = str(out)
        say(f"  plot (base and tool paths, actions numbered): {out}")
    _write_json(args.json, summary)
    if args.gui and plan.success:
        from rlgp_exec.gui import show_plan

        show_plan(scene, timed)
    return EXIT_OK if plan.success else EXIT_FAILED


# ---------------------------------------------------------------------------------- run / replay
def cmd_run(args: argparse.Namespace) -> int:
    import dataclasses

    from rlgp_exec import progress
    from rlgp_exec.executive.runner import RunOptions, run_task
    from rlgp_exec.scene import load_scene

    _limits(args)  # bad limits are refused before the scene loads
    _output_checks(args)
    scene = load_scene(_scene(args.scene))
    if args.perceive:
        if args.backend != "sim":
            raise RlgpError("--perceive renders the head camera in simulation: use it with --backend sim")
        from rlgp_exec.perception.runner import perceive_scene

        with progress.stage(f"perceiving {scene.name}'s tagged objects (head camera, simulation)"):
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
        camera=args.camera,
        calibration=Path(args.calibration) if args.calibration else None,
        **({} if args.camera_hz is None else {"camera_record_hz": args.camera_hz}),
    )
    record = opts.record
    if args.gui and record is None:  # the window plays the run back from its recording
        import tempfile

        record = Path(tempfile.mkdtemp(prefix="rlgp-exec-gui-")) / "run.mcap"
        opts = dataclasses.replace(opts, record=record)
    _print_live_view(args.foxglove)
    with progress.stage(f"running {scene.name} via {args.backend} (sense, plan, time, act, verify)"):
        result, _ = run_task(scene, opts, args.goal)
    say(f"{scene.name}: {result.status.value}: {result.detail}")
    if result.actions:
        say("  plan: " + " ".join(result.actions))
    if result.executed != result.actions:  # a replan, or a task that stopped part-way
        say("  executed: " + (" ".join(result.executed) or "nothing"))
    say(
        f"  planning {result.planning_time_s:.2f} s ({result.plans} plan(s), {result.replans} replan(s)); "
        f"execution {result.execution_time_s:.1f} s; base travelled {result.base_distance_m:.2f} m"
    )
    if args.record:
        say(f"  recorded {args.record}")
    _write_json(args.json, result.as_dict())
    if args.gui and record is not None and record.is_file():
        from rlgp_exec.gui import show_recording

        show_recording(record)
    return EXIT_OK if result.ok else EXIT_FAILED


def cmd_replay(args: argparse.Namespace) -> int:
    from rlgp_exec import progress
    from rlgp_exec.executive.replay import replay

    _output_checks(args)
    with progress.stage(f"replaying {args.file} in PyBullet"):
        report = replay(args.file, png=args.png)  # a bad recording: a RecordingError, exit 2 (main)
    say(report.text())
    if args.animate:
        from rlgp_exec.animate import animate_recording

        with progress.stage(f"rendering the recorded motion to {args.animate}"):
            say(f"  animation: {animate_recording(args.file, args.animate, fps=args.fps, speed=args.speed)}")
    if args.gui:
        from rlgp_exec.gui import show_recording

        show_recording(args.file)
    _write_json(
        args.json,
        {"complete": report.complete, "ending": report.ending, "truncated_at": report.truncated_at,
         "messages": report.messages, "states": report.states,
         "duration_s": report.duration_s, "base_distance_m": report.base_distance_m,
         "transitions": list(report.transitions), "results": list(report.results),
         "collisions": list(report.collisions)},
    )
    return EXIT_OK if not report.collisions else EXIT_FAILED


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

    if args.scene:  # a shipped name or a file, before the config's (file-relative) paths apply
        args.scene = str(_scene(args.scene))
    args = _daemon_settings(args)
    limits = _limits(args)
    scene = load_scene(_scene(args.scene))
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
            camera=args.camera,
            calibration=Path(args.calibration) if args.calibration else None,
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
    code = EXIT_OK
    if daemon.fatal is not None:
        print(f"daemon: {daemon.fatal}", file=sys.stderr)
        code = EXIT_FAILED
    exit_if_threads_linger(code, "daemon")
    return code


def exit_if_threads_linger(code: int, what: str) -> None:
    """End the process now if a worker thread outlived its stop (a join timed out): finalising the interpreter
    under a thread that holds native objects (Ruckig's, OMPL's) prints nanobind's leak dumps. Everything the
    command opened is closed by then; the streams are flushed first."""
    import threading

    ignore = {threading.main_thread(), threading.current_thread()}
    lingering = [t.name for t in threading.enumerate()
                 if t.is_alive() and t not in ignore and not t.name.startswith("progress")]
    if not lingering:
        return
    log.info("%s: threads %s still running after the stop; exiting without waiting for them", what, lingering)
    from rlgp_exec import progress

    progress.stop()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def cmd_request(args: argparse.Namespace) -> int:
    import time

    from rlgp_exec.executive.daemon import DEFAULT_LISTEN, request

    config = _zenoh_config(args)
    endpoint = args.endpoint or (None if config else DEFAULT_LISTEN)
    if args.what == "goal" and not args.literals:
        raise RlgpError("request goal needs at least one literal, e.g. rlgp-exec request goal '(on block tray)'")
    if args.what != "goal" and args.literals:
        raise RlgpError(f"request {args.what} takes no literals (got {args.literals})")
    payload = {"literals": args.literals} if args.what == "goal" else None
    reply = request(endpoint, args.what, payload, args.namespace, zenoh_config=config)
    say(json.dumps(reply, indent=2))
    if not reply.get("ok") and _bad_request(str(reply.get("error", ""))):
        return EXIT_BAD_INPUT
    if args.what == "goal" and args.wait and reply.get("ok"):
        task = reply["task"]
        while True:
            time.sleep(0.5)
            st = request(endpoint, "status", None, args.namespace, zenoh_config=config)
            last = st.get("last") or {}
            if last.get("task") == task:
                say(json.dumps(last, indent=2))
                return 0 if last.get("status") == "succeeded" else 1
            if not st.get("ok"):
                say(json.dumps(st, indent=2))
                return 1
    return EXIT_OK if reply.get("ok") else EXIT_FAILED


def _bad_request(error: str) -> bool:
    """A daemon's refusal of what was asked (a malformed or unknown goal: exit 2), not of when it was asked
    (e-stopped, queue full, shutting down, no daemon: exit 1). The daemon's goal checks all say ``goal: ...``."""
    return error.startswith(("goal: ", "payload over"))


# ---------------------------------------------------------------------------------- rg
def cmd_rg(args: argparse.Namespace) -> int:
    import copy

    import numpy as np

    from rlgp_exec import progress
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

    scene = load_scene(_scene(args.scene))
    model = load_robot(scene.robot.name)
    with progress.stage(f"building (or loading) {scene.name}'s reachability graph ({args.samples} samples)"):
        graph, stats = load_or_build(scene, params=RGParams(samples=args.samples))
    say(
        f"{scene.name}: {graph.G.number_of_nodes()} nodes, {graph.G.number_of_edges()} edges "
        f"({'loaded from cache' if stats.from_cache else f'built in {stats.build_time_s:.2f} s'})"
    )
    before, before_graph = GraphSnapshot(graph), copy.deepcopy(graph)
    checker = WorldChecker(scene, model.manipulator().group)
    planner = ReachabilityPlanner(graph, ReachIK(model, scene, nominal_q(model, scene)), checker, rng_seed=1)
    rng = np.random.default_rng(1)
    lo, hi = graph.X[graph.alive].min(axis=0), graph.X[graph.alive].max(axis=0)
    shown, ok = None, 0
    with progress.stage(f"{args.queries} random task-space queries"):
        for _ in range(args.queries):
            res = planner.query(rng.uniform(lo, hi), rng.uniform(lo, hi))
            ok += res.ok
            if res.ok and (shown is None or len(res.path) > len(shown)):
                shown = res.path
    path_x = None
    if shown is not None:
        tool = model.manipulator().tool_frame
        path_x = np.array([model.fk(q, tool)[:3, 3] for q in shown])
    say(
        f"{args.queries} random queries: {ok} answered; graph now {graph.G.number_of_nodes()} nodes; {planner.counters}"
    )
    if args.png:
        say(f"wrote {draw_graph_png(graph, scene, args.png, before, path_x, before_graph)}")
    checker.close()
    return 0


# ---------------------------------------------------------------------------------- perceive
def cmd_perceive(args: argparse.Namespace) -> int:
    if args.image:
        import numpy as np

        from rlgp_exec.perception.camera import CameraIntrinsics
        from rlgp_exec.perception.runner import perceive_image

        if not args.intrinsics:
            raise RlgpError("--image needs --intrinsics W,H,fx,fy,cx,cy (and --tag-size)")
        tags = perceive_image(args.image, CameraIntrinsics.parse(args.intrinsics), args.tag_size, args.detector)
        for t in tags:
            pos = (
                "-" if not t.get("T_camera_tag") else " ".join(f"{v:+.4f}" for v in np.array(t["T_camera_tag"])[:3, 3])
            )
            say(f"tag {t['tag_id']:4d}  {'ok' if t['ok'] else 'rejected':8s}  t_camera_tag [m] {pos}  {t['reason']}")
        if not tags:
            say("no tags found")
        _write_json(args.json, {"image": args.image, "tags": tags})
        return 0
    if not args.scene:
        raise RlgpError("give a SCENE file, or --image FILE --intrinsics W,H,fx,fy,cx,cy")
    if args.plan:
        return _perceive_and_plan(args)
    from rlgp_exec import progress
    from rlgp_exec.perception.runner import perceive_scene
    from rlgp_exec.scene import load_scene

    scene = load_scene(_scene(args.scene))
    with progress.stage(f"looking around {scene.name} for its tagged objects (rendered head camera)"):
        res = perceive_scene(scene, perturb_m=args.perturb, seed=args.seed, noise_std=args.noise,
                             detector=args.detector)
    say(f"{scene.name}: {res.views} camera views")
    for name in sorted(res.errors_mm):
        err, rot = res.errors_mm[name], res.yaw_errors_deg[name]
        say(f"  {name:20s} position error {err:6.2f} mm  rotation error {rot:5.2f} deg")
    for name in sorted(res.missing):
        say(f"  {name:20s} not seen")
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
    from rlgp_exec import progress
    from rlgp_exec.perceive_plan import perceive_and_plan

    with progress.stage(f"perceiving, then planning with {args.plan}"):
        reports = perceive_and_plan(_scene(args.scene), args.plan.split(","), seed=args.seed, perturb_m=args.perturb)
    for r in reports:
        say(r.text())
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
    ap = argparse.ArgumentParser(description=doc.splitlines()[0], formatter_class=_Help)
    ap.add_argument("--planners", default=planners, help="the planners, comma-separated")
    if robots:
        ap.add_argument("--robot", choices=robots, default=robots[0], help="the robot of the task")
    ap.add_argument("--seed", type=int, default=0, help="the perturbation's seed")
    ap.add_argument("--perturb", type=float, default=perturb_m, help="[m] how far the objects are from the file")
    ap.add_argument("--json", metavar="FILE", help="write the runs as JSON to FILE ('-': stdout)")
    args = ap.parse_args()
    from rlgp_exec.demo import scene_path

    path = scene_path(scene.format(robot=getattr(args, "robot", "")))
    argv = ["perceive", str(path), "--plan", args.planners, "--seed", str(args.seed), "--perturb", str(args.perturb)]
    return main(argv + (["--json", args.json] if args.json else []))


# ---------------------------------------------------------------------------------- demo
def cmd_demo(args: argparse.Namespace) -> int:
    from rlgp_exec.demo import DEMO_SCENE, run_demo
    from rlgp_exec.scene import load_scene

    _output_checks(args)
    path = _scene(args.scene or DEMO_SCENE)
    scene = load_scene(path)  # a bad file is refused before any process starts
    if scene.robot.name != "hsr":
        raise RlgpError(f"demo: {path} is a {scene.robot.name} scene; the demo runs the HSR's Zenoh interface")
    if not any(o.tag is not None for o in scene.objects):
        raise RlgpError(f"demo: {path} has no tagged objects (an [[object]] tag = {{ id, size }}): nothing to perceive")
    from rlgp_exec import progress

    with progress.stage(f"demo on {scene.name} ({path}), files to {args.out}"):
        _print_live_view(args.foxglove)
        report = run_demo(Path(args.out), seed=args.seed, scene_name=str(path), objects=args.objects,
                          foxglove=args.foxglove)
    say(report.text())
    if args.gui and (Path(args.out) / "demo.mcap").is_file():
        from rlgp_exec.gui import show_recording

        show_recording(Path(args.out) / "demo.mcap")
    return EXIT_OK if report.ok else EXIT_FAILED


def _no_default(value: object) -> bool:
    """None, False, "" and argparse's SUPPRESS are no default to show (by identity: 0 is a default)."""
    return value is None or value is False or value is argparse.SUPPRESS or (isinstance(value, str) and not value)


class _Help(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Examples kept as written; every option's default shown, unless it has none (None, False, "") or its
    help already says it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if _no_default(action.default) or "default" in text:
            return text
        if not action.option_strings and action.nargs not in ("?", "*"):
            return text
        return text + " (default: %(default)s)"


def _command(sub: Any, name: str, help: str, examples: str, description: str = "") -> argparse.ArgumentParser:
    """A subcommand with the shared formatter and an examples epilog (one ``rlgp-exec ...`` a line)."""
    lines = [ln.strip() for ln in examples.strip().splitlines() if ln.strip()]
    epilog = "examples:\n" + "\n".join(f"  {ln}" for ln in lines)
    return sub.add_parser(name, help=help, description=description or help, epilog=epilog, formatter_class=_Help)


SCENE_HELP = "a scene file, or a shipped scene's name (e.g. sorting_hsr; a wrong one lists them)"


def _json_flag(s: argparse.ArgumentParser, what: str = "the result") -> None:
    s.add_argument("--json", metavar="FILE",
                   help=f"write {what} as JSON to FILE ('-': stdout, the report then on stderr)")


def _gui_flag(s: argparse.ArgumentParser, what: str) -> None:
    s.add_argument("--gui", action="store_true",
                   help=f"open PyBullet's window and play {what} in it (needs $DISPLAY; without one: exit 2)")


def _animate_flags(s: argparse.ArgumentParser, what: str) -> None:
    s.add_argument("--animate", metavar="FILE", help=f"render {what} to FILE.gif or FILE.mp4 (PyBullet's renderer)")
    s.add_argument("--fps", type=float, default=10.0, help="with --animate: frames per second of the video")
    s.add_argument("--speed", type=float, default=None,
                   help="with --animate: playback speed, x real time (default: the motion in about 30 s of video)")


def _planner_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument("--planner", default="rlgp", choices=PLANNER_CHOICES, metavar="PLANNER",
                   help="the planner, one of: %(choices)s (rlgp: reachability-graph heuristic; lgp: distance-only "
                   "baseline; gnpp and its ablations)")


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
        default=os.environ.get("ZENOH_CONFIG"), metavar="FILE",
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


def _camera_hz(text: str) -> float:
    try:
        hz = float(text)
    except ValueError:
        hz = math.nan
    if not (hz == 0 or 0 < hz <= 30):
        raise argparse.ArgumentTypeError(f"{text!r} is not a rate in (0, 30] Hz, or 0 for no images")
    return hz


def _objects_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--objects", choices=["camera", "mocap", "file"],
        help="where object poses come from (default: zenoh camera, sim its truth, can the file)",
    )
    s.add_argument("--camera", metavar="DEVICE|VIDEO", help="zenoh, --objects camera: a local camera (/dev/video0, "
                   "0, or a video file) mounted as the head camera, in place of the robot's camera topics")
    s.add_argument("--calibration", metavar="FILE", help="the --camera's OpenCV or ROS calibration file (YAML/XML)")


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="rlgp-exec", description="Sense-plan-act executive for mobile manipulators (Toyota HSR, PR2).",
        epilog="exit codes: 0 ok, 1 the task failed (no plan, a failed run), 2 bad input (option, scene, goal, file)\n"
        "examples:\n  rlgp-exec plan sorting_hsr\n  rlgp-exec demo\n  rlgp-exec COMMAND --help",
        formatter_class=_Help,
    )
    ap.add_argument("--version", action="version", version=f"%(prog)s {_version()}")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr (stages, candidates, runs)")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    s = _command(sub, "plan", "plan a scene's task (validated by replay in PyBullet)", """
        rlgp-exec plan sorting_hsr
        rlgp-exec plan my_scene.toml --planner gnpp --time-budget 60
        rlgp-exec plan sorting_hsr --plot plan.png --animate plan.gif
        rlgp-exec plan sorting_hsr --json - | jq .trajectory.duration_s
    """)
    s.add_argument("scene", help=SCENE_HELP)
    _planner_flag(s)
    s.add_argument("--seed", type=int, help="randomise object poses with this seed (0: the file as is, as in bench)")
    _json_flag(s, "the plan's summary and its timed trajectory (docs/trajectory.schema.json)")
    s.add_argument("--trajectory", metavar="FILE",
                   help="write the timed trajectory to FILE instead of into --json ('-': stdout)")
    s.add_argument("--rate", type=float, default=10.0, help="[Hz] the timed trajectory's sample rate")
    s.add_argument("--plot", metavar="PNG",
                   help="write a top view: base and tool paths, each action's place numbered and listed")
    _animate_flags(s, "the planned motion")
    _gui_flag(s, "the planned motion")
    _limit_flags(s)
    s.set_defaults(func=cmd_plan)

    s = _command(sub, "run", "plan and execute a scene's task through a HAL backend", """
        rlgp-exec run sorting_hsr
        rlgp-exec run sorting_hsr --record run.mcap --json run.json
        rlgp-exec run sorting_hsr --backend zenoh --endpoint tcp/127.0.0.1:7447
        rlgp-exec run sorting_hsr --goal '(on block_blue tray_blue)'
    """)
    s.add_argument("scene", help=SCENE_HELP)
    s.add_argument("--backend", choices=["sim", "zenoh", "can"], default="sim", help="the HAL backend")
    s.add_argument("--perceive", action="store_true", help="(sim) initial object poses from AprilTag perception")
    s.add_argument("--record", metavar="FILE", help="write the run to this MCAP file")
    _planner_flag(s)
    s.add_argument("--goal", action="append", help="a goal literal, e.g. '(on block tray)' (repeatable; "
                   "default: the scene's goal)")
    s.add_argument("--endpoint", help="zenoh: the robot's endpoint, e.g. tcp/127.0.0.1:7447")
    s.add_argument("--namespace", default="", help="zenoh: key prefix (default: none)")
    _zenoh_config_flag(s)
    s.add_argument("--seed", type=int, default=0, help="the planner's seed")
    _objects_flag(s)
    _json_flag(s, "the run's result")
    _gui_flag(s, "the run (from its recording, once it ends)")
    _foxglove_flag(s)
    s.add_argument("--camera-hz", type=_camera_hz, default=None, metavar="HZ",
                   help="with the camera in the loop (--objects camera): head camera images (JPEG) recorded and "
                        "served per second of the robot's clock (default 2; 0: none)")
    _limit_flags(s)
    s.set_defaults(func=cmd_run)

    s = _command(sub, "bench", "benchmarks: timing, perception, hal, reachability, executive, scaling, planners", """
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
    _json_flag(s, "the benchmark's records and summary")
    _limit_flags(s)
    s.set_defaults(func=cmd_bench)

    s = _command(sub, "perceive", "detect AprilTags in rendered or given images", """
        rlgp-exec perceive sorting_hsr --perturb 0.03
        rlgp-exec perceive sorting_hsr --plan rlgp,gnpp --perturb 0.03
        rlgp-exec perceive --image frame.png --intrinsics 640,480,554,554,320,240 --tag-size 0.04
    """)
    s.add_argument("scene", nargs="?", help="a scene to look around in simulation for its tagged objects: "
                   + SCENE_HELP)
    s.add_argument("--image", help="an image file (PNG/JPEG) from a real camera instead of a scene")
    s.add_argument("--intrinsics", help="with --image: W,H,fx,fy,cx,cy [px]")
    s.add_argument("--tag-size", type=float, default=0.04, help="with --image: black-square edge [m]")
    s.add_argument("--perturb", type=float, default=0.0, help="move objects up to this far [m] from the file")
    s.add_argument("--noise", type=float, default=2.0, help="pixel noise std [grey levels]")
    s.add_argument("--seed", type=int, default=0, help="the perturbation's and the noise's seed")
    s.add_argument("--detector", choices=["opencv", "pupil"], default="opencv", help="the AprilTag detector")
    s.add_argument(
        "--plan",
        help="then plan on the perceived scene with these planners (comma-separated) and replay each plan "
        "in the true world",
    )
    _json_flag(s, "the detections (or the perceive-and-plan runs)")
    s.set_defaults(func=cmd_perceive)

    s = _command(sub, "sim-robot", "the simulated robot server", """
        rlgp-exec sim-robot --robot hsr --transport zenoh --scene sorting_hsr --endpoint tcp/127.0.0.1:7447
        rlgp-exec sim-robot --robot hsr --transport zenoh --scene sorting_hsr --camera
        rlgp-exec sim-robot --robot pr2 --transport can
    """)
    s.add_argument("--robot", choices=["hsr", "pr2"], required=True, help="the robot to simulate")
    s.add_argument("--transport", choices=["zenoh", "can"], required=True, help="the robot interface it speaks")
    s.add_argument("--scene", help="the world it simulates: " + SCENE_HELP)
    s.add_argument("--endpoint", help="zenoh: the endpoint to listen on, e.g. tcp/127.0.0.1:7447")
    s.add_argument("--namespace", help="zenoh: key prefix, for several robots on one network")
    _zenoh_config_flag(s)
    s.add_argument("--camera", action="store_true", help="zenoh: also publish the head camera (sim.camera_node)")
    s.add_argument("--camera-jpeg", action="store_true", help="with --camera: also sensor_msgs/CompressedImage")
    s.set_defaults(func=cmd_sim_robot)

    s = _command(sub, "daemon", "the on-robot execution daemon (goals over Zenoh queries)", """
        rlgp-exec daemon --scene sorting_hsr
        rlgp-exec daemon --scene sorting_hsr --backend zenoh --endpoint tcp/127.0.0.1:7447 --record-dir runs/
        rlgp-exec daemon --scene my_lab.toml --zenoh-config daemon.json5
    """)
    s.add_argument("--robot", choices=["hsr", "pr2"], default="hsr", help="the robot (must match the scene's)")
    s.add_argument("--backend", choices=["zenoh", "can", "sim"], default="sim", help="the HAL backend")
    s.add_argument("--scene", help="the robot's environment (fixtures, objects): " + SCENE_HELP +
                   " (or scene = \"FILE\" in --config)")
    s.add_argument("--endpoint", help="zenoh backend: the robot's endpoint")
    s.add_argument(
        "--listen", help="where clients connect (goals, status); default tcp/127.0.0.1:7450, or the config's"
    )
    s.add_argument("--namespace", default="", help="key prefix of the daemon's (and the robot's) key space "
                   "(default: none)")
    s.add_argument("--record-dir", metavar="DIR", help="write one MCAP recording per task here")
    _planner_flag(s)
    _zenoh_config_flag(s)
    _objects_flag(s)
    _limit_flags(s)
    _daemon_config_flags(s)
    s.set_defaults(func=cmd_daemon)

    s = _command(sub, "request",
                 "ask a running daemon: goal LITERAL..., cancel, estop, rearm, reset (a FAULT), status", """
        rlgp-exec request goal '(on block_blue tray_blue)' --wait
        rlgp-exec request status
        rlgp-exec request estop
        rlgp-exec request rearm --endpoint tcp/10.0.0.5:7450
    """, description="Ask a running daemon. Exit 0: done; 1: refused now (e-stopped, queue full, no daemon) or "
                 "the task failed (--wait); 2: a bad request (a malformed or unknown goal).")
    s.add_argument("what", choices=["goal", "cancel", "estop", "rearm", "reset", "status"], help="the request")
    s.add_argument("literals", nargs="*", help="for goal: literals such as '(on block tray)' (before the options)")
    s.add_argument("--endpoint", help="the daemon's endpoint; default tcp/127.0.0.1:7450, or the config's")
    s.add_argument("--namespace", default="", help="the daemon's key prefix (default: none)")
    s.add_argument("--wait", action="store_true", help="for goal: wait for the task's result")
    _zenoh_config_flag(s)
    s.set_defaults(func=cmd_request)

    s = _command(sub, "rg", "build/draw a scene's reachability graph", """
        rlgp-exec rg sorting_hsr --png rg.png
        rlgp-exec rg my_scene.toml --samples 400 --queries 50
    """)
    s.add_argument("scene", help=SCENE_HELP)
    s.add_argument("--png", help="draw the graph before and after the queries (top and side views)")
    s.add_argument("--samples", type=int, default=200, help="graph nodes to sample")
    s.add_argument("--queries", type=int, default=20, help="random task-space queries to run")
    s.set_defaults(func=cmd_rg)

    s = _command(sub, "replay", "replay an MCAP recording into PyBullet", """
        rlgp-exec replay run.mcap
        rlgp-exec replay run.mcap --animate run.mp4 --speed 4
        rlgp-exec replay run.mcap --json - | jq .collisions
    """)
    s.add_argument("file", help="an MCAP recording (run --record, daemon --record-dir, demo)")
    s.add_argument("--png", help="a picture of the final replayed state")
    _animate_flags(s, "the recorded motion")
    _gui_flag(s, "the recorded motion")
    _json_flag(s, "the replay's report")
    s.set_defaults(func=cmd_replay)

    s = _command(sub, "show", "render a scene to a PNG (PyBullet camera)", """
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

    s = _command(sub, "demo", "the headless dry run behind `make demo`: sense, plan, act over Zenoh", """
        rlgp-exec demo
        rlgp-exec demo --scene sorting_hsr --out out/sorting
        rlgp-exec demo --scene my_tagged_hsr_scene.toml --seed 3
    """)
    s.add_argument("--out", default="out", metavar="DIR", help="where the pictures, recording and plot go")
    s.add_argument("--scene", default=None,
                   help="an HSR scene with tagged objects: a file or a shipped name (default: table_clearing_hsr)")
    s.add_argument("--seed", type=int, default=0, help="how the true world differs from the file")
    s.add_argument("--objects", choices=["camera", "mocap"], default="camera",
                   help="the executive's object source: the head camera, or the simulation's truth (mocap)")
    _gui_flag(s, "the demo's recorded run (once it ends)")
    _foxglove_flag(s)
    s.set_defaults(func=cmd_demo)
    return ap


def _quiet_imports() -> None:
    """Import the libraries that print banners on import, with the banner dropped (stderr stays clean)."""
    from rlgp_exec.robot.quiet import import_quietly

    import_quietly("pybullet")


def main(argv: list[str] | None = None) -> int:
    # before numpy or IPOPT load OpenBLAS: one thread. The planners' matrices are small (IPOPT's KKT
    # systems, ~1000 rows): BLAS worker threads spin rather than help, and on a 2-core robot PC they take
    # the core the bench's other worker or the executive's perception needs. Set it to override.
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    _quiet_imports()  # first: parsing --planner may load the planners, and they import PyBullet
    args = build_parser().parse_args(argv)
    level = [logging.WARNING, logging.INFO, logging.DEBUG][min(args.verbose, 2)]
    logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
    from rlgp_exec import progress

    _text[0] = sys.stderr if getattr(args, "json", None) == "-" or getattr(args, "trajectory", None) == "-" \
        else sys.stdout
    if not args.quiet:
        progress.start((*PROGRESS_LOGGERS, *STAGE_LOGGERS))
    try:
        return int(args.func(args))
    except RlgpError as e:
        progress.stop()
        print(f"rlgp-exec {args.command}: error: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        return 130
    finally:
        progress.stop()
        _text[0] = sys.stdout


if __name__ == "__main__":
    sys.exit(main())
