"""``demo`` (the headless sense-plan-act dry run) and ``sim-robot`` (the simulated robot server)."""

from __future__ import annotations

import argparse
import subprocess
import sys
import threading
from pathlib import Path
from typing import Any

from rlgp_exec import progress
from rlgp_exec.cli.common import (
    EXIT_FAILED,
    EXIT_OK,
    output_checks,
    print_live_view,
    say,
    scene_arg,
)
from rlgp_exec.cli.flags import (
    SCENE_HELP,
    command,
    foxglove_flag,
    gui_flag,
    zenoh_config_flag,
)
from rlgp_exec.demo import DEMO_OBJECTS
from rlgp_exec.errors import RlgpError
from rlgp_exec.gui import show_recording

__all__ = ["add_demo_commands", "cmd_demo", "cmd_sim_robot"]


def cmd_sim_robot(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.sim.robot_server import main as server_main

    argv = ["--robot", args.robot, "--transport", args.transport]
    if args.scene:
        args.scene = str(scene_arg(args.scene))
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

    # local: per command, so `rlgp-exec --help` stays fast
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
    def pump() -> None:
        for line in proc.stderr:
            if not line.startswith("pybullet build time"):
                sys.stderr.write(line)
                sys.stderr.flush()

    threading.Thread(target=pump, name="child-stderr", daemon=True).start()


def cmd_demo(args: argparse.Namespace) -> int:
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.demo import DEMO_SCENE, run_demo
    from rlgp_exec.scene import load_scene

    output_checks(args)
    path = scene_arg(args.scene or DEMO_SCENE)
    scene = load_scene(path)  # a bad file is refused before any process starts
    if scene.robot.name != "hsr":
        raise RlgpError(f"demo: {path} is a {scene.robot.name} scene; the demo runs the HSR's Zenoh interface")
    if not any(o.tag is not None for o in scene.objects):
        raise RlgpError(f"demo: {path} has no tagged objects (an [[object]] tag = {{ id, size }}): nothing to perceive")

    with progress.stage(f"demo on {scene.name} ({path}), files to {args.out}"):
        print_live_view(args.foxglove)
        report = run_demo(Path(args.out), seed=args.seed, scene_name=str(path), objects=args.objects,
                          foxglove=args.foxglove)
    say(report.text())
    if args.gui and (Path(args.out) / "demo.mcap").is_file():
        show_recording(Path(args.out) / "demo.mcap")
    return EXIT_OK if report.ok else EXIT_FAILED


def add_demo_commands(sub: Any) -> None:
    """The ``sim-robot`` and ``demo`` subcommands."""
    s = command(sub, "sim-robot", "the simulated robot server", """
        rlgp-exec sim-robot --robot hsr --transport zenoh --scene sorting_hsr --endpoint tcp/127.0.0.1:7447
        rlgp-exec sim-robot --robot hsr --transport zenoh --scene sorting_hsr --camera
        rlgp-exec sim-robot --robot pr2 --transport can
    """)
    s.add_argument("--robot", choices=["hsr", "pr2"], required=True, help="the robot to simulate")
    s.add_argument("--transport", choices=["zenoh", "can"], required=True, help="the robot interface it speaks")
    s.add_argument("--scene", help="the world it simulates: " + SCENE_HELP)
    s.add_argument("--endpoint", help="zenoh: the endpoint to listen on, e.g. tcp/127.0.0.1:7447")
    s.add_argument("--namespace", help="zenoh: key prefix, for several robots on one network")
    zenoh_config_flag(s)
    s.add_argument("--camera", action="store_true", help="zenoh: also publish the head camera (sim.camera_node)")
    s.add_argument("--camera-jpeg", action="store_true", help="with --camera: also sensor_msgs/CompressedImage")
    s.set_defaults(func=cmd_sim_robot)

    s = command(sub, "demo", "the headless dry run behind `make demo`: sense, plan, act over Zenoh", """
        rlgp-exec demo
        rlgp-exec demo --scene sorting_hsr --out out/sorting
        rlgp-exec demo --scene my_tagged_hsr_scene.toml --seed 3
    """)
    s.add_argument("--out", default="out", metavar="DIR", help="where the pictures, recording and plot go")
    s.add_argument("--scene", default=None,
                   help="an HSR scene with tagged objects: a file or a shipped name (default: table_clearing_hsr)")
    s.add_argument("--seed", type=int, default=0, help="how the true world differs from the file")
    s.add_argument("--objects", choices=["camera", "mocap"], default=DEMO_OBJECTS,
                   help="the executive's object source: the head camera, or the simulation's truth (mocap)")
    gui_flag(s, "the demo's recorded run (once it ends)")
    foxglove_flag(s)
    s.set_defaults(func=cmd_demo)
