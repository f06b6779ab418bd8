"""Geometric checks of a scene: supports, interpenetration, randomisation ranges."""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import replace

import numpy as np

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.geometry import Box, boxes_overlap, cabinet_geometry, fixture_boxes, object_box, support_surfaces
from rlgp_exec.scene.rules import HEIGHT_MAX, START_OVERLAP
from rlgp_exec.scene.types import IN_HAND, Scene, SceneObject, pose_matrix

__all__ = [
    "STACK_TOLERANCE",
    "SUPPORT_TOLERANCE",
    "check_robot_start",
    "find_support",
    "footprint_radius",
    "validate_geometry",
    "validate_goal_stacks",
]

SUPPORT_TOLERANCE = 0.005  # [m] between an object's bottom and its support surface
STACK_TOLERANCE = 1e-6  # [m] the stackable rule's rounding slack (as the symbolic layer's)

Fail = Callable[[str, str], SceneError]


def footprint_radius(obj: SceneObject) -> float:
    """Half-diagonal of the object's footprint [m]: its reach in the plane at any yaw."""
    return float(np.hypot(obj.size[0], obj.size[1]) / 2)


def find_support(scene: Scene, fail: Fail, openings: Mapping[str, float] | None = None) -> Scene:
    """Fill each object's ``support``: the highest surface under its centre that its bottom touches
    (drawers pulled out by ``openings`` [m], cabinet name -> opening: a sensed world mid-task). The
    object in the hand (``scene.start.held``) rests on nothing: its support is IN_HAND."""
    objs = []
    for o in scene.objects:
        if o.name == scene.start.held:
            objs.append(replace(o, support=IN_HAND))
            continue
        bottom = o.pose[2] - o.size[2] / 2
        xy = np.asarray(o.pose[:2])
        top = o.pose[2] + o.size[2] / 2
        surfaces = [s for s in support_surfaces(scene, exclude=o.name, openings=openings) if s.contains(xy)]
        under = [s for s in surfaces if s.z <= bottom + 0.05]
        touching = [s for s in under if abs(s.z - bottom) <= SUPPORT_TOLERANCE]
        where = f"[[object]] '{o.name}'.pose"
        if touching:
            objs.append(replace(o, support=max(touching, key=lambda s: s.z).name))
            continue
        sunk = [s for s in surfaces if bottom < s.z < top]
        if sunk:
            s0 = max(sunk, key=lambda s: s.z)
            raise fail(where, f"sunk into {s0.name!r}: bottom at z = {bottom:.3f} m, its top at z = {s0.z:.3f} m")
        if bottom <= SUPPORT_TOLERANCE and bottom >= -SUPPORT_TOLERANCE:
            raise fail(where, "rests on the floor; objects must rest on a fixture, a drawer or another object")
        below = max((s for s in under if s.z <= bottom + SUPPORT_TOLERANCE), key=lambda s: s.z, default=None)
        if below is None:
            raise fail(where, f"nothing under the object at {list(o.pose[:2])}: it floats (bottom at {bottom:.3f} m)")
        raise fail(where, f"floating: bottom at z = {bottom:.3f} m, {below.name!r} top at z = {below.z:.3f} m "
                          f"(tolerance {SUPPORT_TOLERANCE * 1000:.0f} mm)")
    return replace(scene, objects=tuple(objs))


def _fixture_parts(scene: Scene) -> list[tuple[str, Box]]:
    """(fixture name, box) of every fixture's boxes, closed drawers included."""
    parts: list[tuple[str, Box]] = []
    for f in scene.fixtures:
        parts += [(f.name, b) for b in fixture_boxes(f)]
        if f.kind == "drawer_cabinet":
            g = cabinet_geometry(f)
            parts += [(f.name, Box(b.name, b.size, g.T_world_drawer_closed @ b.T, b.color)) for b in g.drawer]
    return parts


def _static_boxes(scene: Scene) -> list[Box]:
    return [b for _, b in _fixture_parts(scene)]


def validate_geometry(scene: Scene, fail: Fail) -> None:
    """Fixtures apart, objects on their supports (centre and footprint), no interpenetration, sane random
    ranges."""
    parts = _fixture_parts(scene)
    for i, (owner, part) in enumerate(parts):
        for neighbour, c in parts[:i]:
            if neighbour != owner and boxes_overlap(part, c):
                raise fail(f"[[fixture]] '{owner}'.pose", f"interpenetrates fixture {neighbour!r} (part {c.name!r}); "
                                                         f"fixtures may touch, not overlap")
    statics = [b for _, b in parts]
    surfaces = {s.name: s for s in support_surfaces(scene)}
    obj_boxes = {o.name: object_box(o) for o in scene.objects}
    for o in scene.objects:
        where = f"[[object]] '{o.name}'"
        b = obj_boxes[o.name]
        for s in statics:
            if boxes_overlap(b, s):
                raise fail(f"{where}.pose", f"interpenetrates fixture part {s.name!r}")
        for other in scene.objects:
            if other.name < o.name and boxes_overlap(b, obj_boxes[other.name]):
                raise fail(f"{where}.pose", f"interpenetrates object {other.name!r}")
        if o.random is not None:
            sup = o.support
            if sup not in {f.name for f in scene.fixtures}:
                raise fail(f"{where}.random", f"objects with random poses must rest on a fixture, not on {sup!r}")
            resting = [x.name for x in scene.objects if x.support == o.name]
            if resting:
                raise fail(f"{where}.random", f"cannot randomise: {resting} rest on it")
            surf = surfaces[sup]
            r = footprint_radius(o)
            for axis, rng in ((0, o.random.x), (1, o.random.y)):
                if rng is None:
                    continue
                half = surf.size[axis] / 2 - r
                if rng[0] < -half - 1e-9 or rng[1] > half + 1e-9:
                    name = "xy"[axis]
                    raise fail(f"{where}.random.{name}", f"[{rng[0]}, {rng[1]}] puts the object off {sup!r} "
                                                         f"(its centre must stay within ±{half:.3f} m)")


def check_robot_start(scene: Scene, fail: Fail) -> None:
    """The robot's base footprint (robot.toml: a disc or a rectangle) clear of every fixture's footprint
    at the start, as the planners keep it on every motion (START_OVERLAP)."""
    # local: robot.config brings Pinocchio
    from rlgp_exec.robot.config import load_robot_config

    cfg = load_robot_config(scene.robot.name).base
    x, y, yaw = scene.robot.base
    for f in scene.fixtures:
        R, c = f.T[:2, :2], f.T[:2, 3]
        half = np.asarray(f.size[:2]) / 2
        if cfg.footprint_radius is not None:
            local = R.T @ (np.array([x, y]) - c)
            gap = float(np.linalg.norm(np.maximum(np.abs(local) - half, 0.0))) - cfg.footprint_radius
            inside = gap < -START_OVERLAP
            shape = f"a disc of radius {cfg.footprint_radius} m"
        elif cfg.footprint_half_extents is not None:
            hx, hy = cfg.footprint_half_extents
            # both boxes span the whole height: a footprint test in the plane
            base = Box("base", (2 * hx, 2 * hy, 2 * HEIGHT_MAX), pose_matrix((x, y, 0.0, yaw)), (0, 0, 0, 1))
            fx = Box(f.name, (*f.size[:2], 2 * HEIGHT_MAX), pose_matrix((*f.pose[:2], 0.0, f.pose[3])), (0, 0, 0, 1))
            inside = boxes_overlap(base, fx, tolerance=START_OVERLAP)
            shape = f"{2 * hx:g} x {2 * hy:g} m"
        else:
            return
        if inside:
            raise fail("[robot].base", f"the robot starts inside fixture {f.name!r}: its footprint ({shape}) at "
                                       f"[{x:.3f}, {y:.3f}] overlaps the fixture's {f.size[0]:g} x {f.size[1]:g} m "
                                       f"footprint at [{c[0]:.3f}, {c[1]:.3f}]; the base must start clear of "
                                       f"every fixture")
    hit = _start_contact(scene)
    if hit is not None:
        link, owner, part, depth = hit
        where = "[robot].joints" if scene.robot.joints else "[robot]"
        raise fail(where, f"the robot's start configuration puts link {link!r} {depth * 1000:.0f} mm into fixture "
                          f"{owner!r} (part {part!r}); the robot must start clear of every fixture "
                          f"(START_OVERLAP {START_OVERLAP * 1000:g} mm)")


def _start_contact(scene: Scene) -> tuple[str, str, str, float] | None:
    """(robot link, fixture, fixture part, depth [m]) of the deepest penetration of the robot at its start
    (the home pose with the file's joint overrides) into a fixture, in a PyBullet world of the fixtures'
    boxes; None when it is clear."""
    # local: PyBullet (its import banner) and rlgp_exec.robot (Pinocchio) load only here
    import pybullet as p

    from rlgp_exec.robot import load_robot
    from rlgp_exec.robot.pybullet_body import PyBulletRobot, quat_xyzw

    model = load_robot(scene.robot.name)
    client = p.connect(p.DIRECT)
    try:
        robot = PyBulletRobot(model, client, collision_only=True)
        parts: dict[int, tuple[str, str]] = {}
        for owner, box in _fixture_parts(scene):
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[float(v) / 2 for v in box.size],
                                           physicsClientId=client)
            body = p.createMultiBody(0.0, shape, -1, box.T[:3, 3].tolist(), quat_xyzw(box.T[:3, :3]),
                                     physicsClientId=client)
            parts[body] = (owner, box.name)
        robot.set_q(model.home(scene.robot.base, scene.robot.joints))
        hits = [c for c in robot.contacts(START_OVERLAP) if c.other_body in parts]
    finally:
        p.disconnect(client)
    if not hits:
        return None
    worst = min(hits, key=lambda c: c.distance)
    return (worst.link, *parts[worst.other_body], -worst.distance)


def _footprint(o: SceneObject) -> tuple[float, float]:
    a, b = sorted(o.size[:2])
    return (a, b)


def validate_goal_stacks(scene: Scene, fail: Fail) -> None:
    """The goal's ``(on a b)`` literals with b an object, by the stacking rules the planners keep: b's
    footprint carries a's (the Hanoi rule: a's sorted extents no larger than b's), one object on another
    at most, an object on one support at most, and no object stacked on itself through others."""
    objects = {o.name: o for o in scene.objects}
    on = [(i, lit.args[0], lit.args[1]) for i, lit in enumerate(scene.goal.literals) if lit.predicate == "on"]
    below: dict[str, tuple[int, str]] = {}
    above: dict[str, tuple[int, str]] = {}
    for i, a, b in on:
        where = f"[goal].literals[{i}]"
        text = f"(on {a} {b})"
        if a in below and below[a][1] != b:
            raise fail(where, f"{text}: {a} is also to be on {below[a][1]!r} (literal {below[a][0]}); an object "
                              f"rests on one support")
        below[a] = (i, b)
        if b not in objects:
            continue
        fa, fb = _footprint(objects[a]), _footprint(objects[b])
        if fa[0] > fb[0] + STACK_TOLERANCE or fa[1] > fb[1] + STACK_TOLERANCE:
            raise fail(where, f"{text}: {b}'s footprint {fb[0]:g} x {fb[1]:g} m cannot carry {a}'s "
                              f"{fa[0]:g} x {fa[1]:g} m (stacking rule: the upper footprint's sorted extents no "
                              f"larger than the lower's)")
        if b in above and above[b][1] != a:
            raise fail(where, f"{text}: {above[b][1]} is also to be on {b} (literal {above[b][0]}); one object "
                              f"stacks on another at most")
        above[b] = (i, a)
    for i, a, _ in on:
        chain, x = [a], below[a][1]
        while x in below and x not in chain:
            chain.append(x)
            x = below[x][1]
        if x == a:
            raise fail(f"[goal].literals[{i}]", f"the stack {' on '.join([*chain, a])} puts {a} on itself")
