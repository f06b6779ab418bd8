"""``daemon`` (the on-robot executive, settings from flags and a TOML file) and ``request`` (its client)."""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
from dataclasses import replace
from pathlib import Path
from typing import Any

from rlgp_exec import progress
from rlgp_exec.cli.common import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_OK,
    log,
    plan_limits,
    say,
    scene_arg,
    zenoh_config_path,
)
from rlgp_exec.cli.flags import (
    SCENE_HELP,
    command,
    limit_flags,
    objects_flag,
    planner_flag,
    zenoh_config_flag,
)
from rlgp_exec.errors import RlgpError

__all__ = [
    "add_daemon_commands", "bad_request", "cmd_daemon", "cmd_request", "daemon_settings", "exit_if_threads_linger",
]


_DAEMON_SETTINGS = ("robot", "backend", "scene", "endpoint", "listen", "namespace", "record_dir", "planner",
                    "objects", "time_budget", "max_expansions", "zenoh_config")


def _daemon_config_flags(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--config", metavar="TOML",
        help="the daemon's settings as a TOML file (see docs/daemon.example.toml); options given override it",
    )
    # not given -> None, so that the file's value applies (defaults: DaemonConfig's)
    s.set_defaults(robot=None, backend=None, namespace=None, planner=None, zenoh_config=None)


def daemon_settings(args: argparse.Namespace) -> argparse.Namespace:
    """``args`` with --config's settings where an option was not given (bad ones: RlgpError, exit 2)."""
    # local: per command, so `rlgp-exec --help` stays fast
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
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.executive.daemon import DEFAULT_LISTEN, Daemon, DaemonOptions
    from rlgp_exec.executive.runner import RunOptions
    from rlgp_exec.scene import load_scene

    if args.scene:  # a shipped name or a file, before the config's (file-relative) paths apply
        args.scene = str(scene_arg(args.scene))
    args = daemon_settings(args)
    limits = plan_limits(args)
    scene = load_scene(scene_arg(args.scene))
    if scene.robot.name != args.robot:
        raise RlgpError(f"--scene {args.scene} is for robot {scene.robot.name!r}, not --robot {args.robot!r}")
    config = zenoh_config_path(args)
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
    ignore = {threading.main_thread(), threading.current_thread()}
    lingering = [t.name for t in threading.enumerate()
                 if t.is_alive() and t not in ignore and not t.name.startswith("progress")]
    if not lingering:
        return
    log.info("%s: threads %s still running after the stop; exiting without waiting for them", what, lingering)

    progress.stop()
    logging.shutdown()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def cmd_request(args: argparse.Namespace) -> int:

    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.executive.daemon import DEFAULT_LISTEN, request

    config = zenoh_config_path(args)
    endpoint = args.endpoint or (None if config else DEFAULT_LISTEN)
    if args.what == "goal" and not args.literals:
        raise RlgpError("request goal needs at least one literal, e.g. rlgp-exec request goal '(on block tray)'")
    if args.what != "goal" and args.literals:
        raise RlgpError(f"request {args.what} takes no literals (got {args.literals})")
    payload = {"literals": args.literals} if args.what == "goal" else None
    reply = request(endpoint, args.what, payload, args.namespace, zenoh_config=config)
    say(json.dumps(reply, indent=2))
    if not reply.get("ok") and bad_request(str(reply.get("error", ""))):
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


def bad_request(error: str) -> bool:
    """A daemon's refusal of what was asked (a malformed or unknown goal: exit 2), not of when it was asked
    (e-stopped, queue full, shutting down, no daemon: exit 1). The daemon's goal checks all say ``goal: ...``."""
    return error.startswith(("goal: ", "payload over"))


def add_daemon_commands(sub: Any) -> None:
    """The ``daemon`` and ``request`` subcommands."""
    s = command(sub, "daemon", "the on-robot execution daemon (goals over Zenoh queries)", """
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
    planner_flag(s)
    zenoh_config_flag(s)
    objects_flag(s)
    limit_flags(s)
    _daemon_config_flags(s)
    s.set_defaults(func=cmd_daemon)

    s = command(sub, "request",
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
    zenoh_config_flag(s)
    s.set_defaults(func=cmd_request)
