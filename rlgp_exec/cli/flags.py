"""The options several commands share, and the help formatter (every default shown, examples kept as written)."""

from __future__ import annotations

import argparse
import math
import os
from typing import Any

from rlgp_exec.cli.common import (
    PLANNER_CHOICES,
)

__all__ = [
    "SCENE_HELP", "HelpFormatter", "animate_flags", "camera_hz", "command", "foxglove_flag", "gui_flag",
    "json_flag", "limit_flags", "no_default", "objects_flag", "planner_flag", "tcp_port", "zenoh_config_flag",
]


def no_default(value: object) -> bool:
    """None, False, "" and argparse's SUPPRESS are no default to show (by identity: 0 is a default)."""
    return value is None or value is False or value is argparse.SUPPRESS or (isinstance(value, str) and not value)


class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Examples kept as written; every option's default shown, unless it has none (None, False, "") or its
    help already says it."""

    def _get_help_string(self, action: argparse.Action) -> str:
        text = action.help or ""
        if no_default(action.default) or "default" in text:
            return text
        if not action.option_strings and action.nargs not in ("?", "*"):
            return text
        return text + " (default: %(default)s)"


def command(sub: Any, name: str, help: str, examples: str, description: str = "") -> argparse.ArgumentParser:
    """A subcommand with the shared formatter and an examples epilog (one ``rlgp-exec ...`` a line)."""
    lines = [ln.strip() for ln in examples.strip().splitlines() if ln.strip()]
    epilog = "examples:\n" + "\n".join(f"  {ln}" for ln in lines)
    return sub.add_parser(name, help=help, description=description or help, epilog=epilog,
                          formatter_class=HelpFormatter)


SCENE_HELP = "a scene file, or a shipped scene's name (e.g. sorting_hsr; a wrong one lists them)"


def json_flag(s: argparse.ArgumentParser, what: str = "the result") -> None:
    s.add_argument("--json", metavar="FILE",
                   help=f"write {what} as JSON to FILE ('-': stdout, the report then on stderr)")


def gui_flag(s: argparse.ArgumentParser, what: str) -> None:
    s.add_argument("--gui", action="store_true",
                   help=f"open PyBullet's window and play {what} in it; q or Esc there ends it (needs $DISPLAY; "
                        "without one: exit 2)")


def animate_flags(s: argparse.ArgumentParser, what: str) -> None:
    s.add_argument("--animate", metavar="FILE", help=f"render {what} to FILE.gif or FILE.mp4 (PyBullet's renderer)")
    s.add_argument("--fps", type=float, default=10.0, help="with --animate: frames per second of the video")
    s.add_argument("--speed", type=float, default=None,
                   help="with --animate: playback speed, x real time (default: the motion in about 30 s of video)")


def planner_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument("--planner", default="rlgp", choices=PLANNER_CHOICES, metavar="PLANNER",
                   help="the planner, one of: %(choices)s (rlgp: reachability-graph heuristic; lgp: distance-only "
                   "baseline; gnpp and its ablations)")


def tcp_port(text: str) -> int:
    if not text.isdigit() or not 1 <= int(text) <= 65535:
        raise argparse.ArgumentTypeError(f"{text!r} is not a TCP port (1..65535)")
    return int(text)


def foxglove_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--foxglove", nargs="?", type=tcp_port, const=8765, default=None, metavar="PORT",
        help="serve the run live to Foxglove (robot, TF, scene, plan) on ws://127.0.0.1:PORT (default 8765)",
    )


def zenoh_config_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--zenoh-config",
        default=os.environ.get("ZENOH_CONFIG"), metavar="FILE",
        help="zenoh: a json5 configuration (TLS certificates, access control; default $ZENOH_CONFIG); "
        "an endpoint flag replaces its listen/connect endpoints",
    )


def limit_flags(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--time-budget", type=float, metavar="SECONDS",
        help="CPU time [s] a planning call may spend (> 0; default: the planner's own)",
    )
    s.add_argument(
        "--max-expansions", type=int, metavar="N",
        help="symbolic search expansions (R-LGP's search; GNPP's logic search per iteration; "
        "default: the planner's own)",
    )


def camera_hz(text: str) -> float:
    try:
        hz = float(text)
    except ValueError:
        hz = math.nan
    if not (hz == 0 or 0 < hz <= 30):
        raise argparse.ArgumentTypeError(f"{text!r} is not a rate in (0, 30] Hz, or 0 for no images")
    return hz


def objects_flag(s: argparse.ArgumentParser) -> None:
    s.add_argument(
        "--objects", choices=["camera", "mocap", "file"],
        help="where object poses come from (default: zenoh camera, sim its truth, can the file)",
    )
    s.add_argument("--camera", metavar="DEVICE|VIDEO", help="zenoh, --objects camera: a local camera (/dev/video0, "
                   "0, or a video file) mounted as the head camera, in place of the robot's camera topics")
    s.add_argument("--calibration", metavar="FILE", help="the --camera's OpenCV or ROS calibration file (YAML/XML)")

