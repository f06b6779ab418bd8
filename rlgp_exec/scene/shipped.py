"""The scenes shipped with the package (``sim/scenes/*.toml``), by name."""

from __future__ import annotations

from pathlib import Path

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.loader import load_scene
from rlgp_exec.scene.types import Scene

__all__ = ["SCENES_DIR", "resolve_scene", "shipped_scene", "shipped_scene_names", "shipped_scene_path"]

SCENES_DIR = Path(__file__).resolve().parents[1] / "sim" / "scenes"


def shipped_scene_names() -> list[str]:
    """The shipped scenes' names, sorted (``pick_place_pr2``, ``sorting_hsr``, ...)."""
    return sorted(p.stem for p in SCENES_DIR.glob("*.toml"))


def shipped_scene_path(name: str) -> Path:
    """The file of the shipped scene ``name``; a SceneError lists the valid names."""
    path = SCENES_DIR / f"{name}.toml"
    if "/" in name or not path.is_file():
        raise SceneError(name, "scene", f"no shipped scene of this name; valid: {', '.join(shipped_scene_names())}")
    return path


def resolve_scene(name_or_path: str | Path) -> Path:
    """A scene file given as a path, else as a shipped scene's name (``sorting_hsr``)."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    if p.suffix or "/" in str(name_or_path):
        raise SceneError(str(p), "scene", f"no such file; shipped scenes: {', '.join(shipped_scene_names())}")
    return shipped_scene_path(str(name_or_path))


def shipped_scene(name: str) -> Scene:
    """The shipped scene ``name``, loaded and validated (``load_scene``)."""
    return load_scene(shipped_scene_path(name))
