"""``run`` (plan and execute through a HAL backend) and ``replay`` (a recording into PyBullet)."""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path
from typing import Any

from rlgp_exec import progress
from rlgp_exec.cli.common import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_OK,
    output_checks,
    plan_limits,
    print_live_view,
    say,
    scene_arg,
    write_json,
    zenoh_config_path,
)
from rlgp_exec.cli.flags import (
    SCENE_HELP,
    animate_flags,
    camera_hz,
    command,
    foxglove_flag,
    gui_flag,
    json_flag,
    limit_flags,
    objects_flag,
    planner_flag,
    zenoh_config_flag,
)
from rlgp_exec.errors import RlgpError
from rlgp_exec.gui import show_recording

__all__ = ["add_run_commands", "cmd_replay", "cmd_run"]


def cmd_run(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.executive.runner import RunOptions, run_task
    from rlgp_exec.scene import load_scene

    plan_limits(args)  # bad limits are refused before the scene loads
    output_checks(args)
    scene = load_scene(scene_arg(args.scene))
    if args.perceive:
        if args.backend != "sim":
            raise RlgpError("--perceive renders the head camera in simulation: use it with --backend sim")
        # local: per command, so `rlgp-exec --help` stays fast
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
        zenoh_config=zenoh_config_path(args),
        seed=args.seed,
        objects=args.objects,
        limits=plan_limits(args),
        foxglove=args.foxglove,
        camera=args.camera,
        calibration=Path(args.calibration) if args.calibration else None,
        **({} if args.camera_hz is None else {"camera_record_hz": args.camera_hz}),
    )
    record = opts.record
    if args.gui and record is None:  # the window plays the run back from its recording

        record = Path(tempfile.mkdtemp(prefix="rlgp-exec-gui-")) / "run.mcap"
        opts = dataclasses.replace(opts, record=record)
    print_live_view(args.foxglove)
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
    write_json(args.json, result.as_dict())
    if args.gui and record is not None and record.is_file():
        show_recording(record)
    if result.status.value == "invalid_goal":  # a malformed or unknown --goal is bad input, as in `request goal`
        return EXIT_BAD_INPUT
    return EXIT_OK if result.ok else EXIT_FAILED


def cmd_replay(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.executive.replay import replay

    output_checks(args)
    with progress.stage(f"replaying {args.file} in PyBullet"):
        report = replay(args.file, png=args.png)  # a bad recording: a RecordingError, exit 2 (main)
    say(report.text())
    if args.animate:
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.animate import animate_recording

        with progress.stage(f"rendering the recorded motion to {args.animate}"):
            say(f"  animation: {animate_recording(args.file, args.animate, fps=args.fps, speed=args.speed)}")
    if args.gui:
        show_recording(args.file)
    write_json(
        args.json,
        {"complete": report.complete, "ending": report.ending, "truncated_at": report.truncated_at,
         "messages": report.messages, "states": report.states,
         "duration_s": report.duration_s, "base_distance_m": report.base_distance_m,
         "transitions": list(report.transitions), "results": list(report.results),
         "collisions": list(report.collisions)},
    )
    return EXIT_OK if not report.collisions else EXIT_FAILED


def add_run_commands(sub: Any) -> None:
    """The ``run`` and ``replay`` subcommands."""
    s = command(sub, "run", "plan and execute a scene's task through a HAL backend", """
        rlgp-exec run sorting_hsr
        rlgp-exec run sorting_hsr --record run.mcap --json run.json
        rlgp-exec run sorting_hsr --backend zenoh --endpoint tcp/127.0.0.1:7447
        rlgp-exec run sorting_hsr --goal '(on block_blue tray_blue)'
    """)
    s.add_argument("scene", help=SCENE_HELP)
    s.add_argument("--backend", choices=["sim", "zenoh", "can"], default="sim", help="the HAL backend")
    s.add_argument("--perceive", action="store_true", help="(sim) initial object poses from AprilTag perception")
    s.add_argument("--record", metavar="FILE", help="write the run to this MCAP file")
    planner_flag(s)
    s.add_argument("--goal", action="append", help="a goal literal, e.g. '(on block tray)' (repeatable; "
                   "default: the scene's goal)")
    s.add_argument("--endpoint", help="zenoh: the robot's endpoint, e.g. tcp/127.0.0.1:7447")
    s.add_argument("--namespace", default="", help="zenoh: key prefix (default: none)")
    zenoh_config_flag(s)
    s.add_argument("--seed", type=int, default=0, help="the planner's seed")
    objects_flag(s)
    json_flag(s, "the run's result")
    gui_flag(s, "the run (from its recording, once it ends)")
    foxglove_flag(s)
    s.add_argument("--camera-hz", type=camera_hz, default=None, metavar="HZ",
                   help="with the camera in the loop (--objects camera): head camera images (JPEG) recorded and "
                        "served per second of the robot's clock (default 2; 0: none)")
    limit_flags(s)
    s.set_defaults(func=cmd_run)

    s = command(sub, "replay", "replay an MCAP recording into PyBullet", """
        rlgp-exec replay run.mcap
        rlgp-exec replay run.mcap --animate run.mp4 --speed 4
        rlgp-exec replay run.mcap --json - | jq .collisions
    """)
    s.add_argument("file", help="an MCAP recording (run --record, daemon --record-dir, demo)")
    s.add_argument("--png", help="a picture of the final replayed state")
    animate_flags(s, "the recorded motion")
    gui_flag(s, "the recorded motion")
    json_flag(s, "the replay's report")
    s.set_defaults(func=cmd_replay)
