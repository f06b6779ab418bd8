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

Bounds (``rlgp_exec.scene.rules``, each with its reason): extents in [SIZE_MIN, OBJECT_SIZE_MAX] or
[SIZE_MIN, FIXTURE_SIZE_MAX]; fixture and object centres within WORKSPACE_RADIUS of the base, x and y
within COORD_MAX, yaws within ANGLE_MAX, bottoms not below the floor and tops below HEIGHT_MAX; joint
overrides within their URDF limits (+ JOINT_TOLERANCE); fixtures apart; the robot's base footprint and
its start configuration clear of every fixture (START_OVERLAP); at least one goal literal; goal stacks a
footprint can carry, one object on another, one support per object, no cycle; files of
UTF-8, at most FILE_BYTES_MAX bytes and NESTING_MAX levels.

Every error is a :class:`~rlgp_exec.errors.SceneError` naming the file, the table and the field, with
the bad value quoted shortened (``rules.quote``) and the rule that refuses it.
"""

from __future__ import annotations

import difflib
import math
import tomllib
from pathlib import Path
from types import MappingProxyType
from typing import Any

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.geometry import PANEL
from rlgp_exec.scene.literals import parse_goal
from rlgp_exec.scene.rules import (
    ANGLE_MAX,
    COORD_MAX,
    FILE_BYTES_MAX,
    FIXTURE_SIZE_MAX,
    HEIGHT_MAX,
    ITEMS_MAX,
    JOINT_TOLERANCE,
    LITERALS_MAX,
    MESSAGE_MAX,
    NAME_MAX,
    NESTING_MAX,
    OBJECT_SIZE_MAX,
    SIZE_MIN,
    WORKSPACE_RADIUS,
    quote,
)
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
from rlgp_exec.scene.validate import (
    SUPPORT_TOLERANCE,
    check_robot_start,
    find_support,
    validate_geometry,
    validate_goal_stacks,
)

__all__ = ["load_scene", "scene_from_dict"]

ROBOTS = ("pr2", "hsr")
SHAPES = ("box", "cylinder")
KINDS = ("static", "drawer_cabinet")
TAG36H11_IDS = 587
TOP_KEYS = {"scene", "robot", "fixture", "object", "region", "goal"}
_SOURCE_MAX = 120  # characters of the file name in a message (its end kept: the name, not the folders)
_WHERE_MAX = 100  # characters of a key path in a message


def _clip(text: str, limit: int) -> str:
    return text if len(text) <= limit else text[: limit - 3] + "..."


class _Reader:
    def __init__(self, source: str) -> None:
        self.source = source if len(source) <= _SOURCE_MAX else "..." + source[3 - _SOURCE_MAX :]

    def fail(self, where: str, msg: str) -> SceneError:
        """The SceneError, at most MESSAGE_MAX characters in all (``f"{source}: {where}: {msg}"``)."""
        where = _clip(where, _WHERE_MAX)
        return SceneError(self.source, where, _clip(msg, MESSAGE_MAX - len(self.source) - len(where) - 4))

    def table(self, value: Any, where: str, allowed: set[str], required: set[str]) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise self.fail(where, f"expected a table, got {type(value).__name__}")
        unknown = sorted(quote(k) for k in value if k not in allowed)
        if unknown:
            more = f" and {len(unknown) - 3} more" if len(unknown) > 3 else ""
            raise self.fail(where, f"unknown key(s) [{', '.join(unknown[:3])}{more}]; valid: {sorted(allowed)}")
        missing = sorted(required - set(value))
        if missing:
            raise self.fail(where, f"missing key(s) {missing}")
        return value

    def array(self, value: Any, where: str) -> list[dict[str, Any]]:
        if not isinstance(value, list):
            raise self.fail(where, f"expected an array of tables ([[...]]), got {type(value).__name__}")
        if len(value) > ITEMS_MAX:
            raise self.fail(where, f"{len(value)} entries; a scene holds at most {ITEMS_MAX} (ITEMS_MAX)")
        return value

    def text(self, value: Any, where: str, choices: tuple[str, ...] | None = None) -> str:
        if not isinstance(value, str) or not value.strip():
            raise self.fail(where, f"expected a non-empty string, got {quote(value)}")
        if choices is not None and value not in choices:
            raise self.fail(where, f"unknown value {quote(value)}; valid: {list(choices)}")
        if choices is None:
            if len(value) > NAME_MAX:
                raise self.fail(where, f"a name of {len(value)} characters (at most {NAME_MAX}): {quote(value)}")
            if any(c.isspace() or c in "()" or not c.isprintable() for c in value):
                raise self.fail(where, f"names may not contain spaces, parentheses or control characters: "
                                       f"{quote(value)}")
        return value

    def number(self, value: Any, where: str, positive: bool = False) -> float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise self.fail(where, f"expected a number, got {quote(value)}")
        try:
            x = float(value)
        except OverflowError:
            raise self.fail(where, f"expected a finite number, got {quote(value)}") from None
        if not math.isfinite(x):
            raise self.fail(where, f"expected a finite number, got {quote(value)}")
        if positive and x <= 0:
            raise self.fail(where, f"expected a positive number, got {quote(value)}")
        return x

    def vector(self, value: Any, where: str, n: int, positive: bool = False) -> tuple[float, ...]:
        kind = "positive numbers" if positive else "numbers"
        if not isinstance(value, list) or len(value) != n:
            raise self.fail(where, f"expected {n} {kind}, got {quote(value)}")
        try:
            return tuple(self.number(v, where, positive) for v in value)
        except SceneError:
            raise self.fail(where, f"expected {n} {kind} (finite), got {quote(value)}") from None

    def interval(self, value: Any, where: str) -> tuple[float, float]:
        lo, hi = self.vector(value, where, 2)
        if lo > hi:
            raise self.fail(where, f"empty range [{lo}, {hi}] (lower > upper)")
        return lo, hi

    def within(self, value: float, where: str, what: str, lo: float, hi: float, rule: str) -> None:
        """``value`` in [lo, hi], else an error stating the range and the rule that sets it."""
        if not lo <= value <= hi:
            raise self.fail(where, f"{what} = {value:.6g} is outside [{lo:.6g}, {hi:.6g}] ({rule})")

    def sizes(self, size: tuple[float, ...], where: str, hi: float, rule: str) -> None:
        for k, v in zip("xyz", size, strict=False):
            self.within(v, where, f"{k} extent", SIZE_MIN, hi, f"SIZE_MIN .. {rule}")

    def placed(self, pose: tuple[float, ...], size: tuple[float, ...], where: str) -> None:
        """x, y within the coordinate bound, yaw within a turn each way, bottom to top between the floor
        and HEIGHT_MAX."""
        for k in range(2):
            self.within(pose[k], where, "xy"[k], -COORD_MAX, COORD_MAX, "COORD_MAX: the base's position limits")
        self.within(pose[3], where, "yaw", -ANGLE_MAX, ANGLE_MAX, "ANGLE_MAX: one turn either way")
        bottom, top = pose[2] - size[2] / 2, pose[2] + size[2] / 2
        self.within(bottom, where, "the bottom (z - height / 2)", -SUPPORT_TOLERANCE, HEIGHT_MAX,
                    "not below the floor")
        self.within(top, where, "the top (z + height / 2)", 0.0, HEIGHT_MAX, "HEIGHT_MAX")


def _robot(r: _Reader, data: dict[str, Any], robot_name: str) -> RobotSpec:
    # local: robot brings Pinocchio
    from rlgp_exec.robot import load_robot

    t = r.table(data.get("robot", {}), "[robot]", {"base", "joints"}, {"base"})
    base = r.vector(t["base"], "[robot].base", 3)
    for k in range(2):
        r.within(base[k], "[robot].base", "xy"[k], -COORD_MAX, COORD_MAX, "COORD_MAX: the base's position limits")
    r.within(base[2], "[robot].base", "yaw", -ANGLE_MAX, ANGLE_MAX, "ANGLE_MAX: one turn either way")
    joints: dict[str, float] = {}
    if "joints" in t:
        jt = t["joints"]
        if not isinstance(jt, dict):
            raise r.fail("[robot].joints", f"expected a table of joint = value, got {type(jt).__name__}")
        model = load_robot(robot_name)
        lim = model.limits
        kinds = {j.name: j.type for j in model.urdf.joints}
        valid = sorted(j for g in model.config.groups.values() for j in g)
        for k, v in jt.items():
            where = f"[robot].joints.{_clip(str(k), NAME_MAX)}"
            if k not in valid:
                listed = ", ".join(valid)
                if len(listed) > 200:  # the PR2's 20 joints: the closest names, and where the rest are
                    close = difflib.get_close_matches(str(k)[:NAME_MAX], valid, n=3, cutoff=0.0)
                    listed = f"{', '.join(close)}, ... (the groups in robots/{robot_name}/robot.toml)"
                raise r.fail(where, f"unknown joint for {robot_name}; valid: {listed}")
            x = r.number(v, where)
            i = lim.names.index(k)
            lo, hi = float(lim.lower[i]), float(lim.upper[i])
            unit = "m" if kinds.get(k) == "prismatic" else "rad"
            if not math.isfinite(lo):  # continuous
                r.within(x, where, f"{k} [rad]", -ANGLE_MAX, ANGLE_MAX, "ANGLE_MAX: a continuous joint, one turn "
                                                                       "either way")
            elif not lo - JOINT_TOLERANCE <= x <= hi + JOINT_TOLERANCE:
                raise r.fail(where, f"{x:.6g} {unit} is outside the joint's range [{lo:.4g}, {hi:.4g}] {unit} "
                                    f"(its URDF limits, tolerance {JOINT_TOLERANCE:g})")
            joints[k] = min(max(x, lo), hi)  # past a limit by the tolerance only: held to it, as the planners
    return RobotSpec(robot_name, base, MappingProxyType(joints))  # type: ignore[arg-type]


def _fixture(r: _Reader, t: Any, i: int) -> Fixture:
    where = f"[[fixture]] #{i + 1}"
    t = r.table(t, where, {"name", "shape", "size", "pose", "color", "kind", "drawer"}, {"name", "size", "pose"})
    name = r.text(t["name"], f"{where}.name")
    where = f"[[fixture]] '{name}'"
    shape = r.text(t.get("shape", "box"), f"{where}.shape", SHAPES)
    size = r.vector(t["size"], f"{where}.size", 3, positive=True)
    r.sizes(size, f"{where}.size", FIXTURE_SIZE_MAX, "FIXTURE_SIZE_MAX")
    pose = r.vector(t["pose"], f"{where}.pose", 4)
    r.placed(pose, size, f"{where}.pose")
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
        for key, value, hi in (("travel", drawer.travel, size[0]), ("height", drawer.height, size[2])):
            r.within(value, f"{where}.drawer.{key}", key, SIZE_MIN, hi, "SIZE_MIN .. the cabinet's extent")

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
    r.sizes(size, f"{where}.size", OBJECT_SIZE_MAX, "OBJECT_SIZE_MAX")
    if shape == "cylinder" and abs(size[0] - size[1]) > 1e-9:
        raise r.fail(f"{where}.size", f"a cylinder needs size = [d, d, h], got {list(size)}")
    pose = r.vector(t["pose"], f"{where}.pose", 4)
    r.placed(pose, size, f"{where}.pose")
    color = r.text(t.get("color", "grey"), f"{where}.color", tuple(COLORS))
    tag = None
    if "tag" in t:
        tt = r.table(t["tag"], f"{where}.tag", {"id", "size"}, {"id", "size"})
        tid = tt["id"]
        if isinstance(tid, bool) or not isinstance(tid, int) or not (0 <= tid < TAG36H11_IDS):
            raise r.fail(f"{where}.tag.id", f"expected a tag36h11 id in 0..{TAG36H11_IDS - 1}, got {quote(tid)}")
        tsize = r.number(tt["size"], f"{where}.tag.size", positive=True)
        r.within(tsize, f"{where}.tag.size", "size", SIZE_MIN, OBJECT_SIZE_MAX, "SIZE_MIN .. OBJECT_SIZE_MAX")
        if tsize > min(size[0], size[1]) + 1e-9:
            raise r.fail(f"{where}.tag.size", f"{tsize} m does not fit on the {size[0]} x {size[1]} m top face")
        tag = TagSpec(tid, tsize)
    rnd = None
    if "random" in t:
        rt = r.table(t["random"], f"{where}.random", {"x", "y", "yaw"}, set())
        rnd = RandomRange(*(r.interval(rt[k], f"{where}.random.{k}") if k in rt else None for k in ("x", "y", "yaw")))
        if rnd.yaw is not None:
            for v in rnd.yaw:
                r.within(v, f"{where}.random.yaw", "yaw", -ANGLE_MAX, ANGLE_MAX, "ANGLE_MAX: one turn either way")
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
    r.sizes(size, f"{where}.size", FIXTURE_SIZE_MAX, "FIXTURE_SIZE_MAX")
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
        _check_nesting(r, data)
        return _build(r, data)
    except SceneError:
        raise
    except (TypeError, ValueError, KeyError, AttributeError, IndexError, OverflowError, RecursionError) as e:
        # a shape of input the checks above did not foresee: still the project's own error
        raise r.fail("(scene)", f"malformed scene data: {type(e).__name__}: {_clip(str(e), 120)}") from e


def _check_nesting(r: _Reader, data: Any) -> None:
    """No table or array deeper than NESTING_MAX: nothing of the contract is, and deeper data would
    exhaust the recursion of every later walk over it (copies, reprs, comparisons)."""
    stack: list[tuple[Any, tuple[str, ...]]] = [(data, ())]
    while stack:
        value, path = stack.pop()
        if len(path) >= NESTING_MAX:
            shown = "".join(k if k.startswith("[") else f".{k}" for k in path[:4]).lstrip(".")
            shown += " ..." if len(path) > 4 else ""
            raise r.fail(shown, f"nested deeper than {NESTING_MAX} levels of tables and arrays (NESTING_MAX; "
                                f"the scene contract needs 5)")
        if isinstance(value, dict):
            stack += [(v, (*path, _clip(str(k), 24))) for k, v in value.items() if isinstance(v, dict | list)]
        elif isinstance(value, list):
            stack += [(v, (*path, f"[{i}]")) for i, v in enumerate(value) if isinstance(v, dict | list)]


def _check_workspace(r: _Reader, scene: Scene) -> None:
    """Every fixture and object within WORKSPACE_RADIUS of the robot's start (horizontally)."""
    bx, by = scene.robot.base[0], scene.robot.base[1]
    for table, items in (("[[fixture]]", scene.fixtures), ("[[object]]", scene.objects)):
        for it in items:
            d = math.hypot(it.pose[0] - bx, it.pose[1] - by)
            if d > WORKSPACE_RADIUS:
                raise r.fail(f"{table} '{it.name}'.pose", f"{d:.6g} m from the robot's base at [{bx:.6g}, {by:.6g}]; "
                             f"everything lies within {WORKSPACE_RADIUS:g} m of it (WORKSPACE_RADIUS)")


def _goal_literals(r: _Reader, top: dict[str, Any]) -> list[str]:
    if "goal" not in top:
        raise r.fail("[goal]", "missing: a scene needs a [goal] with literals = [...] (at least one); "
                               "is the file cut short?")
    gt = r.table(top["goal"], "[goal]", {"literals"}, {"literals"})
    lits = gt["literals"]
    if not isinstance(lits, list) or not all(isinstance(x, str) for x in lits):
        raise r.fail("[goal].literals", f"expected a list of strings, got {quote(lits)}")
    if not lits:
        raise r.fail("[goal].literals", "empty: a scene needs at least one goal literal, e.g. \"(on block tray)\"")
    if len(lits) > LITERALS_MAX:
        raise r.fail("[goal].literals", f"{len(lits)} literals; a goal has at most {LITERALS_MAX} (LITERALS_MAX)")
    return lits


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
    literals = _goal_literals(r, top)
    scene = Scene(name, robot, tuple(fixtures), tuple(objects), tuple(regions), Goal(()), r.source)
    _check_workspace(r, scene)
    goal = Goal(parse_goal(literals, scene, r.fail))
    scene = Scene(name, robot, scene.fixtures, scene.objects, scene.regions, goal, r.source)
    scene = find_support(scene, r.fail)
    validate_geometry(scene, r.fail)
    validate_goal_stacks(scene, r.fail)
    check_robot_start(scene, r.fail)
    return scene


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file (UTF-8 TOML, at most FILE_BYTES_MAX bytes). Raises SceneError only."""
    p = Path(path)
    r = _Reader(p.name)
    try:
        with p.open("rb") as f:
            raw = f.read(FILE_BYTES_MAX + 1)
    except OSError as e:
        raise r.fail("(file)", f"cannot read {_clip(str(p), 120)}: {e.strerror or e}") from e
    if len(raw) > FILE_BYTES_MAX:
        raise r.fail("(file)", f"larger than {FILE_BYTES_MAX} bytes (FILE_BYTES_MAX): not a scene file")
    try:
        text = raw.decode("utf-8")
    except UnicodeDecodeError as e:
        line = raw.count(b"\n", 0, e.start) + 1
        col = e.start - (raw.rfind(b"\n", 0, e.start) + 1) + 1
        raise r.fail("(file)", f"not UTF-8 text: byte 0x{raw[e.start]:02x} at line {line}, column {col} "
                               f"(TOML files are UTF-8)") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise r.fail("(toml)", f"not valid TOML: {e}") from e
    except RecursionError:
        raise r.fail("(toml)", "not a scene: arrays or inline tables nested too deep for the TOML parser "
                               f"(a scene nests {NESTING_MAX} levels at most)") from None
    return scene_from_dict(data, r.source)
