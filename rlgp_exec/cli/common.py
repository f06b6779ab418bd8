"""What every command shares: the report's stream, scene arguments, planner names, limits, JSON output.

Library code logs; the CLI is the only place that prints (``say``). ``-`` as a JSON output file is stdout
(the human-readable lines then go to stderr)."""

from __future__ import annotations

import argparse
import json
import logging
import sys
from collections.abc import Iterator
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rlgp_exec import progress
from rlgp_exec.errors import RlgpError
from rlgp_exec.gui import require_display
from rlgp_exec.planning.limits import PlanLimits

if TYPE_CHECKING:
    from rlgp_exec.planning.limits import PlanLimits

__all__ = [
    "EXIT_BAD_INPUT", "EXIT_FAILED", "EXIT_OK", "PLANNER_CHOICES", "output_checks", "package_version",
    "plan_limits", "print_live_view", "progress_line", "say", "scene_arg", "write_json", "zenoh_config_path",
]


log = logging.getLogger("rlgp_exec")


EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT = 0, 1, 2


_text = [sys.stdout]  # where the human-readable lines go: stderr while `--json -` has stdout


def say(*parts: object) -> None:
    """A line of the command's report (stdout, or stderr while stdout carries ``--json -``)."""
    print(*parts, file=_text[0], flush=True)


def package_version() -> str:
    try:
        return version("rlgp-exec")
    except PackageNotFoundError:  # run from a source tree that was never installed
        return "unknown (not installed)"


def scene_arg(arg: str) -> Path:
    """A scene argument (file or shipped name) as a file; RlgpError (exit 2) listing the shipped names."""
    # local: per command, so `rlgp-exec --help` stays fast
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
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.planning.registry import planner_names

        return planner_names()


PLANNER_CHOICES = _Planners()


def plan_limits(args: argparse.Namespace) -> PlanLimits:
    """``--time-budget``/``--max-expansions`` as the planners' limits (bad values: RlgpError, exit 2)."""
    return PlanLimits(args.time_budget, args.max_expansions)


def write_json(path: str | None, data: dict[str, Any]) -> None:
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


def progress_line(msg: str) -> None:
    d = progress.current()
    if d is not None:
        d.line(msg)


def output_checks(args: argparse.Namespace) -> None:
    """Output options refused before any work (a 3-minute plan must not end in 'cannot write')."""
    if getattr(args, "animate", None):
        # local: per command, so `rlgp-exec --help` stays fast
        from rlgp_exec.animate import check_animation_path

        check_animation_path(args.animate)
        if not (args.fps > 0 and (args.speed is None or args.speed > 0)):
            raise RlgpError(f"--fps {args.fps} and --speed {args.speed}: both must be positive")
    rate = getattr(args, "rate", None)
    if rate is not None and not (0 < rate <= 1000):
        raise RlgpError(f"--rate {rate} Hz: must lie in (0, 1000]")
    if getattr(args, "gui", False):
        require_display()
    if getattr(args, "json", None) == "-" and getattr(args, "trajectory", None) == "-":
        raise RlgpError("--json - and --trajectory -: only one of them can have stdout")


def zenoh_config_path(args: argparse.Namespace) -> Path | None:
    """--zenoh-config (default: $ZENOH_CONFIG); read (and an unreadable one named) by session_config."""
    return Path(args.zenoh_config) if args.zenoh_config else None


def print_live_view(port: int | None) -> None:
    if port is not None:
        print(f"live view: open Foxglove, connect to ws://127.0.0.1:{port}", flush=True)

