"""Logging for the simulated robot's processes (``rlgp_exec.sim.robot_server``, ``rlgp_exec.sim.camera_node``)."""

from __future__ import annotations

import logging

__all__ = ["configure_logging"]


def configure_logging(verbose: int) -> None:
    """WARNING, INFO (-v) or DEBUG (-vv) to stderr, unless the process has set up logging already (the CLI)."""
    if not logging.getLogger().handlers:
        level = [logging.WARNING, logging.INFO, logging.DEBUG][min(verbose, 2)]
        logging.basicConfig(level=level, format="%(levelname)s %(name)s: %(message)s")
