"""Whether the open fingers fit round an object at its pinned top grasp, from their own geometry.

A box pick pins the tool point (``factors.grasp_point``) and lets the fingers close along the object's x or
y face axis only (``factors.grasp_top``). Which of those closings has room is a question of where the
fingers are, not of a sphere round the tool point: a 5 cm block 1 cm from a neighbour on two opposite
sides has room for fingers closing across its free sides and none for fingers closing towards the
neighbours. :func:`pick_room` places the finger spheres (tool frame: ``nlp.hand.finger_spheres``, the
box fingers; ``nlp.hand.mesh_finger_spheres``, the mesh fingertips), each with the margin the keyframe
NLP keeps for it, at the pinned tool point for every closing the grasp rows allow (the four face
directions, the approach vertical or leaning by up to ``max_tilt`` on a grid) and measures their clearance
to the standing boxes: the closing with most room, or, when none has any, the boxes that shut each out.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np
import pybullet as p

from rlgp_exec.planning.nlp.hand import link_box_spheres
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene.geometry import Box

__all__ = [
    "FingerSet", "PickRoom", "box_distance", "finger_set", "palm_box_spheres", "pick_room", "too_close",
    "tool_rotation",
]

TILT_STEPS = 5  # leaning approaches tried per axis (symmetric about vertical) when max_tilt > 0
ROUND_YAWS = 24  # closing directions tried round a cylinder, whose fingers may close from any side


class FingerSet(NamedTuple):
    """Spheres on one kind of finger shape (centres in the tool frame (S, 3) [m], radii (S,) [m]) and the
    clearance [m] the keyframe NLP keeps between them and a standing object."""

    centres_tool: FloatArray
    radii: FloatArray
    margin: float


class PickRoom(NamedTuple):
    """The best closing at a pinned grasp: its closing axis (world (3,), unit), its approach axis (world
    (3,), unit), the smallest slack [m] of any finger sphere (distance - radius - margin; >= 0: room), and
    the box nearest to blocking it (its name, '' when no box is near)."""

    closing_world: FloatArray
    approach_world: FloatArray
    slack_m: float
    nearest: str


def finger_set(spheres: Sequence[tuple[FloatArray, float]], margin: float) -> FingerSet:
    """``spheres`` ((centre tool frame (3,), radius) each, as ``nlp.hand`` returns them) as a FingerSet."""
    c = np.array([s for s, _ in spheres], float).reshape(-1, 3)
    return FingerSet(c, np.array([r for _, r in spheres], float), float(margin))


def box_distance(points_world: FloatArray, box: Box) -> FloatArray:
    """Signed distance [m] of each point (N, 3) (world) to ``box``: the exact Euclidean distance outside,
    minus the depth inside."""
    T_inv = np.linalg.inv(box.T)
    local = points_world @ T_inv[:3, :3].T + T_inv[:3, 3]
    q = np.abs(local) - np.asarray(box.size, float) / 2
    outside = np.linalg.norm(np.maximum(q, 0.0), axis=1)
    inside = np.minimum(q.max(axis=1), 0.0)
    return outside + inside


def too_close(tool_point_world: FloatArray, boxes: Sequence[Box], need_m: float) -> list[Box]:
    """The ``boxes`` nearer than ``need_m`` [m] to a pick's pinned tool point (3,) (world): where the tool
    sphere cannot stand for the hand (the surface a flat object stands on, 25 mm below a 5 cm cube's grasp
    point against the PR2's 50 mm tool sphere and margin), so the fingers' own spheres must (``pick_room``
    and the keyframe NLP's finger rows)."""
    point = np.asarray(tool_point_world, float).reshape(1, 3)
    return [b for b in boxes if float(box_distance(point, b)[0]) < need_m]


def tool_rotation(approach_tool: FloatArray, closing_tool: FloatArray, a_world: FloatArray,
                  c_world: FloatArray) -> FloatArray:
    """R_world_tool (3, 3) taking the tool frame's approach and closing axes onto ``a_world`` and
    ``c_world`` (unit, orthogonal)."""
    def basis(a: FloatArray, c: FloatArray) -> FloatArray:
        a = a / np.linalg.norm(a)
        c = c - (c @ a) * a
        c = c / np.linalg.norm(c)
        return np.column_stack([a, c, np.cross(a, c)])

    return basis(np.asarray(a_world, float), np.asarray(c_world, float)) @ basis(
        np.asarray(approach_tool, float), np.asarray(closing_tool, float)).T


def _rotate(axis: FloatArray, angle: float) -> FloatArray:
    """Rotation matrix (3, 3) of ``angle`` [rad] about the unit ``axis`` (3,)."""
    x, y, z = axis
    K = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * K @ K


def _closings(T_obj: FloatArray, max_tilt: float, round_sides: bool) -> list[tuple[FloatArray, FloatArray]]:
    """(approach, closing) world axis pairs the grasp rows allow: closing along +-x or +-y of the object
    (any of ROUND_YAWS horizontal directions if ``round_sides``), the approach down, leaning about either
    horizontal axis by up to ``max_tilt`` [rad]."""
    down = np.array([0.0, 0.0, -1.0])
    tilts = np.linspace(-max_tilt, max_tilt, TILT_STEPS) if max_tilt > 0.0 else np.zeros(1)
    if round_sides:
        yaws = np.linspace(0.0, 2.0 * np.pi, ROUND_YAWS, endpoint=False)
        faces = [np.array([np.cos(w), np.sin(w), 0.0]) for w in yaws]
    else:
        faces = [T_obj[:3, 0], T_obj[:3, 1], -T_obj[:3, 0], -T_obj[:3, 1]]
    out = []
    for face in faces:
        c = np.array([face[0], face[1], 0.0])
        c /= max(float(np.linalg.norm(c)), 1e-12)
        side = np.cross(down, c)
        for axis in (c, side):
            for t in tilts:
                if axis is c or t != 0.0:  # the vertical grasp once per face
                    R = _rotate(axis, float(t))
                    out.append((R @ down, R @ c))
    return out


def pick_room(
    T_obj: FloatArray, tool_point_world: FloatArray, approach_tool: FloatArray, closing_tool: FloatArray,
    fingers: Sequence[FingerSet], boxes: Sequence[Box], max_tilt: float = 0.0, tol: float = 0.0,
    round_sides: bool = False, floor: Sequence[Box] = (), floor_fingers: Sequence[FingerSet] = (),
) -> tuple[PickRoom | None, tuple[str, ...]]:
    """(the closing with most room, None if none has any; for each closing tried with no room, the box
    that shuts it out, most often first, without repeats) at the grasp of an object at ``T_obj`` (4, 4)
    whose tool point is ``tool_point_world`` (3,). ``approach_tool``/``closing_tool``: the manipulator's
    axes in its tool frame; ``fingers``: the finger spheres and their margins; ``boxes``: the standing
    objects (not the one being grasped) and anything else the fingers must keep off; a closing has room
    when no sphere is short of its clearance by more than ``tol`` [m]. ``round_sides``: a cylinder's grasp,
    closing from any side (on a grid of ROUND_YAWS). ``floor``: boxes (the surface under the object) checked
    with ``floor_fingers`` instead (``fingers`` if empty)."""
    sets = [f for f in fingers if len(f.radii)]
    floor_sets = [f for f in floor_fingers if len(f.radii)] or sets
    pairs = [(b, sets) for b in boxes] + [(b, floor_sets) for b in floor]
    best: PickRoom | None = None
    blockers: dict[str, int] = {}
    for a_w, c_w in _closings(T_obj, max_tilt, round_sides):
        R = tool_rotation(approach_tool, closing_tool, a_w, c_w)
        slack, nearest = np.inf, ""
        for b, with_sets in pairs:
            for f in with_sets:
                d = box_distance(f.centres_tool @ R.T + tool_point_world, b) - f.radii - f.margin
                m = float(d.min())
                if m < slack:
                    slack, nearest = m, b.name
        room = PickRoom(c_w, a_w, float(slack), nearest)
        if slack < -tol:
            blockers[nearest] = blockers.get(nearest, 0) + 1
        elif best is None or slack > best.slack_m:
            best = room
    order = sorted(blockers, key=lambda n: -blockers[n])
    return best, tuple(order)


def palm_box_spheres(robot, model, q: FloatArray) -> list[tuple[FloatArray, float]]:
    """(centre in the tool frame (3,) [m], radius [m]) spheres on the box shapes of the links rigid with
    the first manipulator's palm frame (the palm link and its ancestors up to the one the last moving joint
    carries: the HSR's wrist box; none for the PR2's mesh palm), at ``q``: the hand's body round a pick,
    which the palm's one arm sphere covers too coarsely beside a neighbour as high as the grasped object."""
    links, name = [], model.manipulator().palm_frame
    while name in robot.link_index and name != "world":
        links.append(name)
        info = p.getJointInfo(robot.id, robot.link_index[name], physicsClientId=robot.client)
        if info[2] != p.JOINT_FIXED:
            break
        name = robot.parent_link[name]
    return link_box_spheres(robot, model, q, links)
