"""``scene_to_dict``: a Scene back to the scene-file data (the inverse of ``scene_from_dict``), so a
perceived or re-planned world can be recorded as JSON/TOML and loaded again with full validation."""

from __future__ import annotations

from typing import Any

from rlgp_exec.scene.types import Scene

__all__ = ["scene_to_dict", "scene_to_toml"]


def scene_to_dict(scene: Scene) -> dict[str, Any]:
    """The scene-file tables of ``scene`` (``scene_from_dict(scene_to_dict(s), src)`` rebuilds it)."""
    robot: dict[str, Any] = {"base": list(scene.robot.base)}
    if scene.robot.joints:
        robot["joints"] = dict(scene.robot.joints)
    fixtures = []
    for f in scene.fixtures:
        d: dict[str, Any] = {
            "name": f.name,
            "shape": f.shape,
            "size": list(f.size),
            "pose": list(f.pose),
            "color": f.color,
            "kind": f.kind,
        }
        if f.drawer is not None:
            d["drawer"] = {"travel": f.drawer.travel, "knob_height": f.drawer.knob_height, "height": f.drawer.height}
        fixtures.append(d)
    objects = []
    for o in scene.objects:
        d = {"name": o.name, "shape": o.shape, "size": list(o.size), "pose": list(o.pose), "color": o.color}
        if o.tag is not None:
            d["tag"] = {"id": o.tag.id, "size": o.tag.size}
        if o.random is not None:
            d["random"] = {
                k: list(v)
                for k, v in zip(("x", "y", "yaw"), (o.random.x, o.random.y, o.random.yaw), strict=True)
                if v is not None
            }
        objects.append(d)
    regions = [
        {"name": r.name, "on": r.on, "size": list(r.size), "offset": list(r.offset), "color": r.color}
        for r in scene.regions
    ]
    return {
        "scene": {"name": scene.name, "robot": scene.robot.name},
        "robot": robot,
        "fixture": fixtures,
        "object": objects,
        "region": regions,
        "goal": {"literals": [str(lit) for lit in scene.goal.literals]},
    }


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(float(v)) if isinstance(v, float) else str(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(x)}" for k, x in v.items()) + " }"
    raise TypeError(f"cannot write {type(v).__name__} to TOML")


def scene_to_toml(scene: Scene) -> str:
    """``scene`` as a scene file (TOML) that ``load_scene`` reads back to an equal Scene."""
    data = scene_to_dict(scene)
    out = [f"# written by rlgp-exec from {scene.source}"]
    for table in ("scene", "robot", "goal"):
        out.append(f"\n[{table}]")
        out += [f"{k} = {_toml_value(v)}" for k, v in data[table].items()]
    for array in ("fixture", "region", "object"):
        for item in data[array]:
            out.append(f"\n[[{array}]]")
            out += [f"{k} = {_toml_value(v)}" for k, v in item.items()]
    return "\n".join(out) + "\n"
