"""Scene files (TOML) -> :class:`~rlgp_exec.scene.types.Scene`, with validation.

Field reference (units: metres, radians; poses are [x, y, z of the centre, yaw] in the world):

``[scene]``     ``name`` (str), ``robot`` ("pr2" | "hsr").
``[robot]``     ``base`` [x, y, yaw]; ``joints`` (optional) {joint = value} overriding the home pose.
``[[fixture]]`` ``name``; ``shape`` "box" | "cylinder" (default box); ``size`` [sx, sy, sz] full
                extents; ``pose``; ``color`` (palette, default grey); ``kind`` "static" (default) |
                "drawer_cabinet"; for a cabinet ``drawer = { travel, knob_height, height = 0.15 }``
                (opens along the cabinet's local +x; the drawer is centred on knob_height).
``[[object]]``  ``name``; ``shape`` "box" | "cylinder" (size [d, d, h]); ``size``; ``pose`` (it must
                rest on a fixture top, a cabinet top, a drawer bottom or another object's top);
                ``color``; ``tag = { id, size }`` (tag36h11, id 0..586, centred on the top face);
                ``random = { x = [lo, hi], y = [lo, hi], yaw = [lo, hi] }`` (per seed, the centre in
                the support's frame; objects with ``random`` must rest on a fixture).
``[[region]]``  ``name``; ``on`` (a static box fixture); ``size`` [sx, sy]; ``offset`` [dx, dy] from
                the fixture's top centre in its frame (default [0, 0]); ``color``.
``[goal]``      ``literals``: "(on OBJ TARGET)" (TARGET a region, fixture or object),
                "(in OBJ CABINET)", "(open CABINET)", "(closed CABINET)".

Every error is a :class:`~rlgp_exec.errors.SceneError` naming the file, the table and the field.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from types import MappingProxyType
from typing import Any

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.literals import parse_goal
from rlgp_exec.scene.types import (
    COLORS,
    DrawerSpec,
    Fixture,
    Goal,
    RandomRange,
    Region,
    RobotSpec,
    Scene,
    SceneObject,
    TagSpec,
)
from rlgp_exec.scene.validate import find_support, validate_geometry

__all__ = ["load_scene", "scene_from_dict"]

ROBOTS = ("pr2", "hsr")
SHAPES = ("box", "cylinder")
KINDS = ("static", "drawer_cabinet")
TAG36H11_IDS = 587
TOP_KEYS = {"scene", "robot", "fixture", "object", "region", "goal"}


class _Reader:
    def __init__(self, source: str) -> None:
        self.source = source

    def fail(self, where: str, msg: str) -> SceneError:
        return SceneError(self.source, where, msg)

    def table(self, value: Any, where: str, allowed: set[str], required: set[str]) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"expected a table, got {type(value).__name__}")
        unknown = sorted(k for k in value if k not in allowed)
        if unknown:
            raise self.fail(where, f"unknown key(s) {unknown}; valid: {sorted(allowed)}")
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(where, f"missing key(s) {missing}")
        return value

    def array(self, value: Any, where: str) -> list[dict[str, Any]]:
        if not isinstance(value, list):
            raise self.fail(where, f"expected an array of tables ([[...]]), got {type(value).__name__}")
        return value

    def text(self, value: Any, where: str, choices: tuple[str, ...] | None = None) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(where, f"expected a non-empty string, got {value!r}")
        if choices is not None and value not in choices:
            raise self.fail(where, f"unknown value {value!r}; valid: {list(choices)}")
        if choices is None and (any(c.isspace() or c in "()" for c in value)):
            raise self.fail(where, f"names may not contain spaces or parentheses: {value!r}")
        return value

    def number(self, value: Any, where: str, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(where, f"expected a number, got {value!r}")
        x = float(value)
        if not math.isfinite(x):
            raise self.fail(where, f"expected a finite number, got {value!r}")
        if positive and x <= 0:
            raise self.fail(where, f"expected a positive number, got {value!r}")
        return x

    def vector(self, value: Any, where: str, n: int, positive: bool = False) -> tuple[float, ...]:
        kind = "positive numbers" if positive else "numbers"
        if not isinstance(value, list) or len(value) != n:
            raise self.fail(where, f"expected {n} {kind}, got {value!r}")
        try:
            return tuple(self.number(v, where, positive) for v in value)
        except SceneError:
            raise self.fail(where, f"expected {n} {kind}, got {value!r}") from None

    def interval(self, value: Any, where: str) -> tuple[float, float]:
        lo, hi = self.vector(value, where, 2)
        if lo > hi:
            raise self.fail(where, f"empty range [{lo}, {hi}] (lower > upper)")
        return lo, hi


def _robot(r: _Reader, data: dict[str, Any], robot_name: str) -> RobotSpec:
    from rlgp_exec.robot.config import load_robot_config

    t = r.table(data.get("robot", {}), "[robot]", {"base", "joints"}, {"base"})
    base = r.vector(t["base"], "[robot].base", 3)
    joints: dict[str, float] = {}
    if "joints" in t:
        jt = t["joints"]
        if not isinstance(jt, dict):
            raise r.fail("[robot].joints", f"expected a table of joint = value, got {type(jt).__name__}")
        cfg = load_robot_config(robot_name)
        valid = sorted(j for g in cfg.groups.values() for j in g)
        for k, v in jt.items():
            if k not in valid:
                raise r.fail(f"[robot].joints.{k}", f"unknown joint for {robot_name}; valid: {valid}")
            joints[k] = r.number(v, f"[robot].joints.{k}")
    return RobotSpec(robot_name, base, MappingProxyType(joints))  # type: ignore[arg-type]


def _fixture(r: _Reader, t: Any, i: int) -> Fixture:
    where = f"[[fixture]] #{i + 1}"
    t = r.table(t, where, {"name", "shape", "size", "pose", "color", "kind", "drawer"}, {"name", "size", "pose"})
    name = r.text(t["name"], f"{where}.name")
    where = f"[[fixture]] '{name}'"
    shape = r.text(t.get("shape", "box"), f"{where}.shape", SHAPES)
    size = r.vector(t["size"], f"{where}.size", 3, positive=True)
    pose = r.vector(t["pose"], f"{where}.pose", 4)
    color = r.text(t.get("color", "grey"), f"{where}.color", tuple(COLORS))
    kind = r.text(t.get("kind", "static"), f"{where}.kind", KINDS)
    drawer = None
    if kind == "drawer_cabinet":
        if shape != "box":
            raise r.fail(f"{where}.shape", "a drawer_cabinet must be a box")
        if "drawer" not in t:
            raise r.fail(f"{where}.drawer", "a drawer_cabinet needs drawer = { travel, knob_height }")
        d = r.table(t["drawer"], f"{where}.drawer", {"travel", "knob_height", "height"}, {"travel", "knob_height"})
        drawer = DrawerSpec(
            travel=r.number(d["travel"], f"{where}.drawer.travel", positive=True),
            knob_height=r.number(d["knob_height"], f"{where}.drawer.knob_height", positive=True),
            height=r.number(d.get("height", 0.15), f"{where}.drawer.height", positive=True),
        )
        from rlgp_exec.scene.geometry import PANEL

        depth = size[0] - 2.5 * PANEL
        if drawer.travel > depth - 2 * PANEL:
            raise r.fail(f"{where}.drawer.travel",
                         f"{drawer.travel} m exceeds the drawer depth ({depth - 2 * PANEL:.3f} m)")
        bottom, top = pose[2] - size[2] / 2 + PANEL, pose[2] + size[2] / 2 - PANEL
        lo, hi = drawer.knob_height - drawer.height / 2 - 0.005, drawer.knob_height + drawer.height / 2 + 0.005
        if lo < bottom or hi > top:
            raise r.fail(f"{where}.drawer.knob_height", f"the drawer (height {drawer.height} m centred at "
                         f"{drawer.knob_height} m) does not fit between {bottom:.3f} and {top:.3f} m")
    elif "drawer" in t:
        raise r.fail(f"{where}.drawer", "only a fixture of kind = \"drawer_cabinet\" has a drawer")
    if shape == "cylinder" and abs(size[0] - size[1]) > 1e-9:
        raise r.fail(f"{where}.size", f"a cylinder needs size = [d, d, h], got {list(size)}")
    return Fixture(name, shape, size, pose, color, kind, drawer)  # type: ignore[arg-type]


def _object(r: _Reader, t: Any, i: int) -> SceneObject:
    where = f"[[object]] #{i + 1}"
    t = r.table(t, where, {"name", "shape", "size", "pose", "color", "tag", "random"}, {"name", "size", "pose"})
    name = r.text(t["name"], f"{where}.name")
    where = f"[[object]] '{name}'"
    shape = r.text(t.get("shape", "box"), f"{where}.shape", SHAPES)
    size = r.vector(t["size"], f"{where}.size", 3, positive=True)
    if shape == "cylinder" and abs(size[0] - size[1]) > 1e-9:
        raise r.fail(f"{where}.size", f"a cylinder needs size = [d, d, h], got {list(size)}")
    pose = r.vector(t["pose"], f"{where}.pose", 4)
    color = r.text(t.get("color", "grey"), f"{where}.color", tuple(COLORS))
    tag = None
    if "tag" in t:
        tt = r.table(t["tag"], f"{where}.tag", {"id", "size"}, {"id", "size"})
        tid = tt["id"]
        if isinstance(tid, bool) or not isinstance(tid, int) or not (0 <= tid < TAG36H11_IDS):
            raise r.fail(f"{where}.tag.id", f"expected a tag36h11 id in 0..{TAG36H11_IDS - 1}, got {tid!r}")
        tsize = r.number(tt["size"], f"{where}.tag.size", positive=True)
        if tsize > min(size[0], size[1]) + 1e-9:
            raise r.fail(f"{where}.tag.size", f"{tsize} m does not fit on the {size[0]} x {size[1]} m top face")
        tag = TagSpec(tid, tsize)
    rnd = None
    if "random" in t:
        rt = r.table(t["random"], f"{where}.random", {"x", "y", "yaw"}, set())
        rnd = RandomRange(*(r.interval(rt[k], f"{where}.random.{k}") if k in rt else None for k in ("x", "y", "yaw")))
    return SceneObject(name, shape, size, pose, color, support="", tag=tag, random=rnd)  # type: ignore[arg-type]


def _region(r: _Reader, t: Any, i: int, fixtures: dict[str, Fixture]) -> Region:
    where = f"[[region]] #{i + 1}"
    t = r.table(t, where, {"name", "on", "size", "offset", "color"}, {"name", "on", "size"})
    name = r.text(t["name"], f"{where}.name")
    where = f"[[region]] '{name}'"
    on = r.text(t["on"], f"{where}.on")
    fx = fixtures.get(on)
    if fx is None or fx.kind != "static" or fx.shape != "box":
        valid = sorted(n for n, f in fixtures.items() if f.kind == "static" and f.shape == "box")
        raise r.fail(f"{where}.on", f"{on!r} is not a static box fixture; valid: {valid}")
    size = r.vector(t["size"], f"{where}.size", 2, positive=True)
    offset = r.vector(t.get("offset", [0.0, 0.0]), f"{where}.offset", 2)
    for k in range(2):
        if abs(offset[k]) + size[k] / 2 > fx.size[k] / 2 + 1e-6:
            raise r.fail(f"{where}.size", f"the region hangs off fixture {on!r} (size {list(fx.size[:2])})")
    color = r.text(t.get("color", "grey"), f"{where}.color", tuple(COLORS))
    return Region(name, on, size, offset, color)  # type: ignore[arg-type]


def scene_from_dict(data: Any, source: str) -> Scene:
    """Validate a parsed scene (the TOML's dict) and build the Scene. Raises SceneError only."""
    r = _Reader(source)
    try:
        return _build(r, data)
    except SceneError:
        raise
    except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError) as e:
        # a shape of input the checks above did not foresee: still the project's own error
        raise r.fail("(scene)", f"malformed scene data: {type(e).__name__}: {e}") from e


def _build(r: _Reader, data: Any) -> Scene:
    top = r.table(data, "(top level)", TOP_KEYS, {"scene", "robot"})
    st = r.table(top["scene"], "[scene]", {"name", "robot"}, {"name", "robot"})
    name = r.text(st["name"], "[scene].name")
    robot = _robot(r, top, r.text(st["robot"], "[scene].robot", ROBOTS))
    fixtures = [_fixture(r, t, i) for i, t in enumerate(r.array(top.get("fixture", []), "[[fixture]]"))]
    objects = [_object(r, t, i) for i, t in enumerate(r.array(top.get("object", []), "[[object]]"))]
    fx_by_name = {f.name: f for f in fixtures}
    regions = [_region(r, t, i, fx_by_name) for i, t in enumerate(r.array(top.get("region", []), "[[region]]"))]
    seen: dict[str, str] = {}
    for table, items in (("[[fixture]]", fixtures), ("[[object]]", objects), ("[[region]]", regions)):
        for it in items:
            if it.name in seen:
                raise r.fail(f"{table} '{it.name}'.name", f"duplicate name (also a {seen[it.name]})")
            seen[it.name] = table
    gt = r.table(top.get("goal", {"literals": []}), "[goal]", {"literals"}, {"literals"})
    if not isinstance(gt["literals"], list) or not all(isinstance(x, str) for x in gt["literals"]):
        raise r.fail("[goal].literals", f"expected a list of strings, got {gt['literals']!r}")
    scene = Scene(name, robot, tuple(fixtures), tuple(objects), tuple(regions), Goal(()), r.source)
    goal = Goal(parse_goal(gt["literals"], scene, r.fail))
    scene = Scene(name, robot, scene.fixtures, scene.objects, scene.regions, goal, r.source)
    scene = find_support(scene, r.fail)
    validate_geometry(scene, r.fail)
    return scene


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file."""
    p = Path(path)
    source = p.name
    try:
        text = p.read_text()
    except OSError as e:
        raise SceneError(source, "(file)", f"cannot read {p}: {e.strerror or e}") from e
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise SceneError(source, "(toml)", f"not valid TOML: {e}") from e
    return scene_from_dict(data, source)
