"""``rlgp-exec daemon --config daemon.toml``: the daemon's deployment as a file.

One flat TOML table; every key is optional and is the daemon's command-line option of the same name
(``record_dir`` is ``--record-dir``), which overrides it. Relative paths are relative to the file::

    robot = "hsr"                  # hsr | pr2
    backend = "zenoh"              # zenoh | can | sim
    scene = "lab.toml"             # the robot's environment (fixtures, objects)
    endpoint = "tcp/10.0.0.2:7447" # zenoh backend: the robot
    listen = "tls/0.0.0.0:7450"    # where clients connect (default: the zenoh config's, else loopback)
    namespace = "hsr1"
    record_dir = "recordings"      # one MCAP per task
    planner = "rlgp"
    objects = "camera"             # camera | mocap | file
    time_budget = 60.0             # [s] CPU time per plan
    max_expansions = 2000
    zenoh_config = "session.json5" # TLS certificates, access control

Unknown keys, values of the wrong type and values outside their choices are refused with an
:class:`~rlgp_exec.errors.RlgpError` naming the key and what it may be (the CLI exits 2).
"""

from __future__ import annotations

import math
import tomllib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, fields, replace
from pathlib import Path
from typing import Any

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.runner import OBJECT_SOURCES
from rlgp_exec.planning.registry import planner_names

__all__ = ["DaemonConfig", "load_daemon_config"]


@dataclass(frozen=True)
class DaemonConfig:
    """The daemon's settings (module docstring); None: the option's own default."""

    robot: str = "hsr"
    backend: str = "sim"
    scene: Path | None = None
    endpoint: str | None = None
    listen: str | None = None
    namespace: str = ""
    record_dir: Path | None = None
    planner: str = "rlgp"
    objects: str | None = None
    time_budget: float | None = None  # [s] CPU time per plan
    max_expansions: int | None = None
    zenoh_config: Path | None = None

    def merged(self, overrides: Mapping[str, Any]) -> DaemonConfig:
        """A copy with every non-None value of ``overrides`` (the command line) in place (checked)."""
        given = {k: v for k, v in overrides.items() if v is not None}
        unknown = sorted(set(given) - set(KEYS))
        if unknown:
            raise RlgpError(f"daemon settings: unknown {unknown}; valid: {list(KEYS)}")
        return replace(self, **{k: _CHECKS[k]("command line", k, v, Path.cwd()) for k, v in given.items()})


def _choice(valid: Callable[[], list[str]]) -> Callable[[str, str, Any, Path], str]:
    def check(where: str, key: str, v: Any, _: Path) -> str:
        if not isinstance(v, str) or v not in valid():
            raise RlgpError(f"{where}: {key} = {v!r}: valid: {valid()}")
        return v

    return check


def _text(where: str, key: str, v: Any, _: Path) -> str:
    if not isinstance(v, str):
        raise RlgpError(f"{where}: {key} = {v!r}: expected a string")
    return v


def _path(where: str, key: str, v: Any, base: Path) -> Path:
    if not isinstance(v, str | Path) or not str(v):
        raise RlgpError(f"{where}: {key} = {v!r}: expected a path (a non-empty string)")
    p = Path(v).expanduser()
    return p if p.is_absolute() else base / p


def _seconds(where: str, key: str, v: Any, _: Path) -> float:
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v <= 0:
        raise RlgpError(f"{where}: {key} = {v!r}: expected a positive number of seconds (CPU time per plan)")
    return float(v)


def _count(where: str, key: str, v: Any, _: Path) -> int:
    if isinstance(v, bool) or not isinstance(v, int) or v < 1:
        raise RlgpError(f"{where}: {key} = {v!r}: expected a positive whole number")
    return v


def _planners() -> list[str]:
    return planner_names()


def _sources() -> list[str]:
    return list(OBJECT_SOURCES)


_CHECKS: dict[str, Callable[[str, str, Any, Path], Any]] = {
    "robot": _choice(lambda: ["hsr", "pr2"]),
    "backend": _choice(lambda: ["zenoh", "can", "sim"]),
    "scene": _path,
    "endpoint": _text,
    "listen": _text,
    "namespace": _text,
    "record_dir": _path,
    "planner": _choice(_planners),
    "objects": _choice(_sources),
    "time_budget": _seconds,
    "max_expansions": _count,
    "zenoh_config": _path,
}
KEYS = tuple(f.name for f in fields(DaemonConfig))
assert set(KEYS) == set(_CHECKS)


def load_daemon_config(path: str | Path) -> DaemonConfig:
    """Read and check ``path`` (module docstring); RlgpError naming the file and the key otherwise."""
    p = Path(path)
    try:
        data = tomllib.loads(p.read_text())
    except OSError as e:
        raise RlgpError(f"cannot read daemon config {p}: {e.strerror or e}") from e
    except UnicodeDecodeError as e:
        raise RlgpError(f"daemon config {p}: not UTF-8 text ({e.reason} at byte {e.start})") from e
    except tomllib.TOMLDecodeError as e:
        raise RlgpError(f"daemon config {p}: not valid TOML: {e}") from e
    unknown = sorted(set(data) - set(KEYS))
    if unknown:
        raise RlgpError(f"daemon config {p}: unknown key(s) {unknown}; valid: {list(KEYS)}")
    base = p.resolve().parent
    return DaemonConfig(**{k: _CHECKS[k](f"daemon config {p}", k, v, base) for k, v in data.items()})
