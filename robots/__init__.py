"""Robot descriptions shipped with rlgp-exec: one folder per robot (URDF, robot.toml, driver maps)."""

from __future__ import annotations

from pathlib import Path

__all__ = ["ROBOTS", "robot_dir"]

ROBOTS: tuple[str, ...] = ("hsr", "pr2")


def robot_dir(name: str) -> Path:
    """The folder holding ``name``'s description files."""
    if name not in ROBOTS:
        raise KeyError(f"unknown robot {name!r}; valid: {list(ROBOTS)}")
    return Path(__file__).resolve().parent / name
