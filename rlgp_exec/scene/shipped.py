"""The scenes shipped with the package (``sim/scenes/*.toml``), and a scene given on the command line: a path
to a scene file, or the name of a shipped scene.

Every command that takes a scene resolves it here, so ``rlgp-exec plan sorting_hsr`` and
``rlgp-exec plan ./my_scene.toml`` both work and a wrong one gets the same error listing the shipped names.
"""

from __future__ import annotations

from pathlib import Path

from rlgp_exec.errors import RlgpError
from rlgp_exec.scene.loader import load_scene
from rlgp_exec.scene.types import Scene

__all__ = ["resolve_scene", "shipped_scene", "shipped_scene_dir", "shipped_scene_path", "shipped_scenes"]


def shipped_scene_dir() -> Path:
    """The directory of the shipped scene files (``sim/scenes``)."""
    return Path(__file__).resolve().parents[1] / "sim" / "scenes"


def shipped_scenes() -> list[str]:
    """The shipped scenes' names (file stems), sorted."""
    return sorted(p.stem for p in shipped_scene_dir().glob("*.toml"))


def shipped_scene_path(name: str) -> Path:
    """The file of the shipped scene ``name`` (``sorting_hsr``); RlgpError lists the valid names."""
    if name not in shipped_scenes():
        raise RlgpError(f"no shipped scene {name!r}; shipped: {', '.join(shipped_scenes())}")
    return shipped_scene_dir() / f"{name}.toml"


def shipped_scene(name: str) -> Scene:
    """The shipped scene ``name``, loaded and validated (``load_scene``)."""
    return load_scene(shipped_scene_path(name))


def resolve_scene(arg: str | Path) -> Path:
    """``arg`` as a scene file: an existing path as given, else a shipped scene's name (``sorting_hsr``
    or ``sorting_hsr.toml``). Neither: RlgpError naming the argument and the shipped names."""
    text = str(arg)
    if not text:
        raise RlgpError(f"empty scene argument; give a scene file or one of the shipped scenes: {shipped_scenes()}")
    path = Path(text).expanduser()
    if path.is_file():
        return path
    if path.exists():
        raise RlgpError(f"scene {text!r} is not a file (a directory?)")
    name = path.name[: -len(".toml")] if path.name.endswith(".toml") else path.name
    if path.parent == Path(".") and name in shipped_scenes():
        return shipped_scene_dir() / f"{name}.toml"
    raise RlgpError(f"scene {text!r}: no such file and not a shipped scene; shipped: {', '.join(shipped_scenes())}")
