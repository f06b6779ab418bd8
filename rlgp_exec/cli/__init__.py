"""``rlgp-exec``, the command line: the parser and entry point in ``main``, one module per command group."""

from rlgp_exec.cli.main import build_parser, main, task_script

__all__ = ["build_parser", "main", "task_script"]
