"""``rlgp-exec``: the command line (the contract of DESIGN.md): the parser and the entry point.

Every subcommand returns an exit code: 0 success, 1 the task failed (e.g. no plan), 2 bad input (a bad option,
scene, goal or file). A scene argument is a scene file or a shipped scene's name (``scene_arg``). Progress goes
to stderr (``progress``). Each command module imports its heavy dependencies inside its functions, so that
``--help`` and a bad option answer without loading the planners or PyBullet."""

from __future__ import annotations

import argparse
import logging
import os
import sys
from typing import TYPE_CHECKING

from rlgp_exec.cli.common import (
    EXIT_BAD_INPUT,
    _text,
    package_version,
)
from rlgp_exec.cli.flags import (
    HelpFormatter,
)
from rlgp_exec.errors import RlgpError

if TYPE_CHECKING:
    pass
from rlgp_exec import progress
from rlgp_exec.cli.bench import add_bench_command
from rlgp_exec.cli.daemon import add_daemon_commands
from rlgp_exec.cli.demo import add_demo_commands
from rlgp_exec.cli.perceive import add_perceive_commands
from rlgp_exec.cli.plan import add_plan_commands
from rlgp_exec.cli.run import add_run_commands

__all__ = ["build_parser", "main", "task_script"]


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


def build_parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(
        prog="rlgp-exec", description="Sense-plan-act executive for mobile manipulators (Toyota HSR, PR2).",
        epilog="exit codes: 0 ok, 1 the task failed (no plan, a failed run), 2 bad input (option, scene, goal, file)\n"
        "examples:\n  rlgp-exec plan sorting_hsr\n  rlgp-exec demo\n  rlgp-exec COMMAND --help",
        formatter_class=HelpFormatter,
    )
    ap.add_argument("--version", action="version", version=f"%(prog)s {package_version()}")
    ap.add_argument("-v", "--verbose", action="count", default=0, help="more logging (-v info, -vv debug)")
    ap.add_argument("-q", "--quiet", action="store_true", help="no progress on stderr (stages, candidates, runs)")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")
    add_plan_commands(sub)
    add_run_commands(sub)
    add_bench_command(sub)
    add_perceive_commands(sub)
    add_demo_commands(sub)
    add_daemon_commands(sub)
    return ap


def _quiet_imports() -> None:
    """Import the libraries that print banners on import, with the banner dropped (stderr stays clean)."""
    # local: rlgp_exec.robot loads Pinocchio; importing the CLI stays light
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


def task_script(doc: str, scene: str, planners: str, perturb_m: float = 0.03, robots: tuple[str, ...] = ()) -> int:
    """The ``tools/1x_*.py`` perception-to-plan scripts: ``perceive SCENE --plan PLANNERS`` on a shipped
    scene with that script's defaults. ``scene`` may hold ``{robot}`` when ``robots`` lists the choices."""
    ap = argparse.ArgumentParser(description=doc.splitlines()[0], formatter_class=HelpFormatter)
    ap.add_argument("--planners", default=planners, help="the planners, comma-separated")
    if robots:
        ap.add_argument("--robot", choices=robots, default=robots[0], help="the robot of the task")
    ap.add_argument("--seed", type=int, default=0, help="the perturbation's seed")
    ap.add_argument("--perturb", type=float, default=perturb_m, help="[m] how far the objects are from the file")
    ap.add_argument("--json", metavar="FILE", help="write the runs as JSON to FILE ('-': stdout)")
    args = ap.parse_args()
    # local: per command, so `rlgp-exec --help` stays fast
    from rlgp_exec.demo import scene_path

    path = scene_path(scene.format(robot=getattr(args, "robot", "")))
    argv = ["perceive", str(path), "--plan", args.planners, "--seed", str(args.seed), "--perturb", str(args.perturb)]
    return main(argv + (["--json", args.json] if args.json else []))

