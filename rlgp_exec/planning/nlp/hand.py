"""The open hand in the keyframe NLP: spheres along the fingers, fixed in the tool frame.

The arm spheres of ``nlp.factors`` stop at the tool point; an open gripper reaches further sideways
(the HSR's open fingers span about 25 cm), which is what hits a wall next to an object or the carcass
above a knob. :func:`finger_spheres` reads the finger links' box collision shapes in PyBullet at the
nominal configuration (the hand open) and covers each box with a row of spheres along its long axis
(every point of the box inside one), in the tool frame; :func:`points_clear` keeps them clear of
boxes. Links whose shapes are meshes get none (their hull is not a box): for them (the PR2's fingers)
the PyBullet keyframe check decides, with the objects where they stand.

Self-collision proxy (:func:`self_clear`): spheres on the arm kept clear of the link the arm is mounted
on (the HSR's base cylinder: a low, level arm otherwise rests on it; the PR2's torso: the upper arm
otherwise swings into it).
"""

from __future__ import annotations

import itertools
import math
import weakref
import xml.etree.ElementTree as ET
from collections.abc import Sequence
from typing import NamedTuple

import casadi as ca
import numpy as np
import pybullet as p
from scipy.spatial.transform import Rotation

from rlgp_exec.planning.margins import SELF_MARGIN
from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows
from rlgp_exec.reach.ik import arm_spheres, box_sdf, box_sdf_columns
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.robot.pybullet_body import pose_to_matrix
from rlgp_exec.scene.geometry import Box

__all__ = [
    "SelfRows",
    "arm_link_spheres",
    "body_obstacles",
    "cover_refusal",
    "finger_spheres",
    "inner_obstacles",
    "link_box_spheres",
    "mesh_finger_spheres",
    "mesh_finger_tips",
    "other_arm_obstacles",
    "points_clear",
    "points_clear_moving",
    "self_clear",
    "self_rows_function",
    "upper_arm_spheres",
]

SEGMENT_RADIUS = 0.06  # [m] spheres on a mesh arm's segments (the PR2's upper arm and forearm)
SHOULDER_SETBACK = 0.02  # [m] a mesh body's box ends this far behind the arm's first joint
MID_INSET = 0.09  # [m] a mesh body's chest box (``inner_obstacles``) ends this far inside each shoulder's axis
TIP_TILT = 0.8  # [rad] the approach directions (beyond the grasps' largest lean) ``mesh_finger_tips`` keeps
TIP_STEPS = 5  # per axis, over [-TIP_TILT, TIP_TILT]
BOUND_YAWS = 12  # base headings over a quarter turn at which a link's bounding box is taken (``_link_bounds``)


MAX_COVER_SPHERES = 64  # spheres at most in a box's cover (a thin box gets a coarser row, ``_box_cover``)
MAX_COVER_BULGE = 0.01  # [m] how far a coarser row may reach out past the box's long edges, beyond the usual


def _box_cover(size: FloatArray, max_spheres: int = MAX_COVER_SPHERES) -> list[tuple[FloatArray, float]]:
    """Spheres (centre in the box frame (3,), radius [m]) in a row along a box's long axis that cover
    the whole box: spaced s <= the cross-section's half diagonal c, radius sqrt((s/2)^2 + c^2), the
    first and last s/2 from the ends; at most ``max_spheres`` of them (a thinner box's row is coarser:
    its spheres reach further past its edges, ``cover_refusal``)."""
    long = int(np.argmax(size))
    length = float(size[long])
    c = float(np.hypot(*np.delete(size, long))) / 2
    n = min(max_spheres, max(1, math.ceil(length / c))) if c > 0 else max_spheres
    s = length / n
    r = math.hypot(s / 2, c)
    out = []
    for j in range(n):
        centre = np.zeros(3)
        centre[long] = -length / 2 + s / 2 + j * s
        out.append((centre, r))
    return out


def cover_refusal(size: FloatArray, max_spheres: int = MAX_COVER_SPHERES) -> str | None:
    """Why a box of ``size`` [m] has no sphere cover of at most ``max_spheres`` within ``MAX_COVER_BULGE`` of
    what the uncapped cover reaches past its sides (a long, thin box: a pole), or None."""
    size = np.asarray(size, float)
    if size.shape != (3,) or not np.all(np.isfinite(size)) or np.any(size < 0):
        return f"box size {size.tolist()}: expected 3 finite sizes >= 0 [m]"
    c = float(np.hypot(*np.delete(size, int(np.argmax(size))))) / 2
    r = _box_cover(size, max_spheres)[0][1]
    if r - math.hypot(c / 2, c) > MAX_COVER_BULGE:
        return (f"box {np.round(size, 6).tolist()} m: {max_spheres} spheres reach {r - c:.3f} m past its sides "
                f"(a fine cover's {math.hypot(c / 2, c) - c:.3f} m, at most {MAX_COVER_BULGE:.3f} m more)")
    return None


def finger_spheres(robot, model, q: FloatArray) -> list[tuple[FloatArray, float]]:
    """(centre in the tool frame (3,) [m], radius [m]) spheres on the finger links' box shapes at ``q``."""
    links = [n for n in model.manipulator().links if "finger" in n]
    return link_box_spheres(robot, model, q, links)


def link_box_spheres(robot, model, q: FloatArray, links: Sequence[str]) -> list[tuple[FloatArray, float]]:
    """(centre in the first manipulator's tool frame (3,) [m], radius [m]) spheres covering the box
    collision shapes of ``links`` at ``q`` (PyBullet's shapes; mesh shapes get none)."""
    manip = model.manipulator()
    robot.set_q(q)
    T_tool = model.fk(q, manip.tool_frame)
    out: list[tuple[FloatArray, float]] = []
    for name in links:
        i = robot.link_index[name]
        st = p.getLinkState(robot.id, i, computeForwardKinematics=True, physicsClientId=robot.client)
        T_com = pose_to_matrix(st[0], st[1])
        for d in p.getCollisionShapeData(robot.id, i, physicsClientId=robot.client):
            if d[2] != p.GEOM_BOX:
                continue
            size = np.asarray(d[3], float)
            T_shape = T_com @ pose_to_matrix(d[5], d[6])
            for centre, r in _box_cover(size):
                pw = T_shape @ np.r_[centre, 1.0]
                out.append((np.linalg.solve(T_tool, pw)[:3], r))
    return out


def _grid_cover(lo: FloatArray, hi: FloatArray, cell: float) -> list[tuple[FloatArray, float]]:
    """Spheres (centre (3,), radius [m]) covering the box [lo, hi] (its frame): a grid of cells no longer
    than ``cell`` [m] along any axis, one sphere round each cell (radius: the cell's half diagonal)."""
    size = np.maximum(np.asarray(hi, float) - np.asarray(lo, float), 1e-6)
    n = np.maximum(1, np.ceil(size / cell - 1e-9)).astype(int)
    step = size / n
    r = float(np.linalg.norm(step)) / 2
    return [(np.asarray(lo, float) + (np.array(ijk) + 0.5) * step, r)
            for ijk in itertools.product(*(range(int(k)) for k in n))]


def _tip_vertices(robot, model, q: FloatArray) -> list[FloatArray]:
    """The vertices (tool frame (V, 3) [m]) of each fingertip mesh collision shape (the links named ``*tip*``,
    else every finger link) at ``q``."""
    fingers = [n for n in model.manipulator().links if "finger" in n]
    links = [n for n in fingers if "tip" in n] or fingers
    robot.set_q(q)
    T_tool = model.fk(q, model.manipulator().tool_frame)
    out = []
    for name in links:
        i = robot.link_index[name]
        st = p.getLinkState(robot.id, i, computeForwardKinematics=True, physicsClientId=robot.client)
        T_com = pose_to_matrix(st[0], st[1])
        for k, d in enumerate(p.getCollisionShapeData(robot.id, i, physicsClientId=robot.client)):
            if d[2] != p.GEOM_MESH:
                continue
            mesh = p.getMeshData(robot.id, i, collisionShapeIndex=k, flags=p.MESH_DATA_SIMULATION_MESH,
                                 physicsClientId=robot.client)
            v = np.asarray(mesh[1], float)  # in the link's inertial frame, the shape's offset and scale applied
            if len(v) >= 4:
                out.append((np.linalg.solve(T_tool, T_com @ np.c_[v, np.ones(len(v))].T)[:3]).T)
    return out


def _tip_boxes(robot, model, q: FloatArray) -> list[tuple[FloatArray, FloatArray, FloatArray, FloatArray]]:
    """Each fingertip mesh's vertices (``_tip_vertices``) bounded by a box in the mesh's principal axes:
    (centre (3,), axes (3, 3) rows, lower (3,), upper (3,)), in the tool frame [m]."""
    out = []
    for v_tool in _tip_vertices(robot, model, q):
        centre = v_tool.mean(axis=0)
        axes = np.linalg.svd(v_tool - centre, full_matrices=False)[2]  # rows: principal axes
        local = (v_tool - centre) @ axes.T
        out.append((centre, axes, local.min(axis=0), local.max(axis=0)))
    return out


def mesh_finger_spheres(robot, model, q: FloatArray) -> list[tuple[FloatArray, float]]:
    """(centre in the tool frame (3,) [m], radius [m]) spheres on the fingertips' *mesh* collision shapes
    (``_tip_boxes``) at ``q`` (the hand open; ``finger_spheres`` covers box shapes): each mesh's vertices
    (its convex hull, what PyBullet collides) bounded by a box in the mesh's principal axes, covered by a
    grid of cells about as long as the box is thin (the PR2's tips: 6 spheres each, radius 1.8 cm, 7 mm
    proud of the tip's faces; none on the HSR's box fingers). The keyframe NLP keeps them off the objects,
    for which PyBullet's keyframe check otherwise rejects a solution (PR2 fingertips a centimetre into a
    neighbouring block: one restart each)."""
    out: list[tuple[FloatArray, float]] = []
    for centre, axes, lo, hi in _tip_boxes(robot, model, q):
        for c, r in _grid_cover(lo, hi, 1.1 * max(float(np.min(hi - lo)), 0.01)):
            out.append((centre + axes.T @ c, r))
    return out


def mesh_finger_tips(
    robot, model, q: FloatArray, max_tilt: float = TIP_TILT, steps: int = TIP_STEPS,
) -> list[tuple[FloatArray, float]]:
    """The fingertips' mesh vertices that lead the hand (tool frame (3,) [m], radius 0): each mesh's furthest
    vertex along the approach axis turned by up to ``max_tilt`` [rad] (a grid of ``steps`` per axis). Against
    a flat surface below the hand, whose nearest point of a convex tip is such a vertex, they bound the tips
    exactly, where ``mesh_finger_spheres`` reach 7 mm further (a 3 cm disc grasped at half its height: the
    spheres 0.7 mm into the table, the PR2's tips 8 mm above it)."""
    m = model.manipulator()
    a = np.asarray(m.approach, float) / np.linalg.norm(m.approach)
    side1 = np.cross(a, np.asarray(m.closing, float))
    side1 /= np.linalg.norm(side1)
    side2 = np.cross(a, side1)
    tilts = np.linspace(-max_tilt, max_tilt, steps)
    dirs = [np.cos(np.hypot(t1, t2)) * a + np.sin(t1) * side1 + np.sin(t2) * side2 for t1 in tilts for t2 in tilts]
    out: list[tuple[FloatArray, float]] = []
    for v in _tip_vertices(robot, model, q):
        for i in sorted({int(np.argmax(v @ d)) for d in dirs}):
            out.append((v[i].copy(), 0.0))
    return out


def points_clear(
    T_tool: ca.SX, spheres: list[tuple[FloatArray, float]], boxes: list[Box], rows: Rows, margin: float = 0.0
) -> None:
    """Every sphere (tool frame) at least its radius (plus ``margin`` [m]) from every box (per box, all
    spheres at once: ``box_sdf_columns``)."""
    if not boxes or not spheres:
        return
    C = ca.DM(np.array([c for c, _ in spheres], float).T)  # (3, S) tool frame
    pw = T_tool[:3, :3] @ C + ca.repmat(T_tool[:3, 3], 1, len(spheres))  # (3, S) world
    lower = [r + margin for _, r in spheres]
    for b in boxes:
        Tinv = np.linalg.inv(b.T)
        rows.add_all(box_sdf_columns(ca.DM(Tinv[:3, :3]) @ pw, Tinv[:3, 3], np.asarray(b.size) / 2), lower, ca.inf)


def points_clear_moving(
    T_tool: ca.SX, spheres: list[tuple[FloatArray, float]], T_box: ca.SX, size: FloatArray, rows: Rows,
    margin: float = 0.0,
) -> None:
    """``points_clear`` for one box whose pose T_world_box (4, 4) is itself an expression (an object set
    down at another keyframe: the hand there times the grasp); its rotation is taken as rigid."""
    half = np.asarray(size, float) / 2
    R, t = T_box[:3, :3], T_box[:3, 3]
    for c, r in spheres:
        pw = T_tool[:3, :3] @ ca.DM(c) + T_tool[:3, 3]
        rows.add(box_sdf(R.T @ (pw - t), half), r + margin, ca.inf)


_CYLINDERS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # model -> ``_urdf_cylinders(model)``


def _urdf_cylinders(model) -> dict[str, list[tuple[FloatArray, float, float]]]:
    """link -> [(T_link_cylinder (4, 4), radius, length)] from the URDF's collision cylinders; read once
    per model (models are shared and read-only; re-reading the PR2's URDF took
    ~25 ms, twice per planning call).
    The result is shared: callers must not modify it."""
    cyl = _CYLINDERS.get(model)
    if cyl is None:
        cyl = _CYLINDERS[model] = _read_cylinders(model)
    return cyl


def _read_cylinders(model) -> dict[str, list[tuple[FloatArray, float, float]]]:

    root = ET.fromstring(model.urdf.pinocchio_xml)
    out: dict[str, list[tuple[FloatArray, float, float]]] = {}
    for link in root.findall("link"):
        for col in link.findall("collision"):
            cyl = col.find("geometry/cylinder")
            if cyl is None:
                continue
            o = col.find("origin")
            xyz = [float(v) for v in (o.get("xyz", "0 0 0") if o is not None else "0 0 0").split()]
            rpy = [float(v) for v in (o.get("rpy", "0 0 0") if o is not None else "0 0 0").split()]
            T = np.eye(4)
            T[:3, :3] = Rotation.from_euler("xyz", rpy).as_matrix()
            T[:3, 3] = xyz
            r, length = float(cyl.get("radius", "0")), float(cyl.get("length", "0"))
            out.setdefault(str(link.get("name")), []).append((T, r, length))
    return out


def arm_link_spheres(model, manipulator: str | None = None) -> list[tuple[str, FloatArray, float]]:
    """(frame, centre in that frame (3,), radius [m]) spheres on the arm for the self-clearance rows: on
    the arm links' collision cylinders (three per cylinder, on its axis; the first joint's link, which
    rides the body, excluded), else (mesh arms: PR2) the arm spheres from the elbow on."""
    m = model.manipulator(manipulator)
    cyl = _urdf_cylinders(model)
    out: list[tuple[str, FloatArray, float]] = []
    joints = [model.joint_names[i] for i in model.group(m.group)]
    for j in joints[1:]:
        link = j.removesuffix("_joint") + "_link"
        for T, r, length in cyl.get(link, []):
            for s in (-0.5, 0.0, 0.5):
                out.append((link, (T @ np.r_[0.0, 0.0, s * max(length - 2 * r, 0.0), 1.0])[:3], r))
    if not out:  # mesh arms: spheres along each segment between consecutive joint frames, and the joints
        q = model.home()
        frames = list(dict.fromkeys(f for f, _ in arm_spheres(model, manipulator)))
        for f, g in itertools.pairwise(frames):
            rel = np.linalg.solve(model.fk(q, f), np.r_[model.fk(q, g)[:3, 3], 1.0])[:3]  # g's origin in f
            if np.linalg.norm(rel) > 0.05:
                out += [(f, s * rel, SEGMENT_RADIUS) for s in (0.0, 0.35, 0.65)]
        out += [(f, np.zeros(3), r) for f, r in arm_spheres(model, manipulator)[2:]]
    return out


def body_obstacles(robot, model, q: FloatArray, manipulator: str | None = None) -> list[tuple[str, Box]]:
    """(frame, box in that frame) of the link the arm is mounted on: its collision cylinders from the URDF
    (the HSR's base; a box beside them is the column the arm rides along, left out), else its PyBullet
    bounding box at ``q`` (a mesh: the PR2's torso)."""
    m = model.manipulator(manipulator)
    parent = _mount_link(robot, model, m.group)
    cyl = _urdf_cylinders(model).get(parent, [])
    if cyl:
        return [(parent, Box("body", (2 * r, 2 * r, length), T, (0.0, 0.0, 0.0, 1.0))) for T, r, length in cyl]
    lo_l, hi_l, shoulder = _body_bounds(robot, model, q, m.group, parent)
    # the shoulders are mounted on the box's front: keep only what lies SHOULDER_SETBACK behind them
    hi_l[0] = min(hi_l[0], float(shoulder[0]) - SHOULDER_SETBACK)
    return [(parent, _bounds_box("body", lo_l, hi_l))]


def _mount_link(robot, model, group: str) -> str:
    """The link the first joint of ``group`` is mounted on (its PyBullet parent)."""
    first = robot.joint_index[model.joint_names[model.group(group)[0]]]
    return robot.link_name.get(p.getJointInfo(robot.id, first, physicsClientId=robot.client)[16], "base_link")


def _body_bounds(robot, model, q: FloatArray, group: str, parent: str) -> tuple[FloatArray, FloatArray, FloatArray]:
    """The mesh body's bounds (lower (3,), upper (3,)) and the arm's first joint (3,) [m], in its frame at q."""
    lo_l, hi_l = _link_bounds(robot, model, q, parent)
    first_joint = model.joint_names[model.group(group)[0]]
    shoulder = np.linalg.solve(model.fk(q, parent), np.r_[model.fk(q, first_joint)[:3, 3], 1.0])[:3]
    return lo_l, hi_l, shoulder


def inner_obstacles(robot, model, q: FloatArray, manipulator: str | None = None) -> list[tuple[str, Box]]:
    """(frame, box in that frame) an arm turned inwards reaches with its upper arm, which ``body_obstacles``
    leaves out: a mesh body's chest (in front of the box behind the shoulders, MID_INSET inside each
    shoulder's axis) and every other arm's first link where q holds it. pick_place_pr2 seeds 5, 9, 15,
    16 lost keyframe starts to an upper arm 0.7-1.6 cm into the torso's mesh and 2.2 cm into the tucked
    left shoulder (the shoulder pan at its inner limit). Empty for a body of cylinders (the HSR)."""
    m = model.manipulator(manipulator)
    parent = _mount_link(robot, model, m.group)
    if _urdf_cylinders(model).get(parent):
        return []
    lo_l, hi_l, shoulder = _body_bounds(robot, model, q, m.group, parent)
    half = abs(float(shoulder[1])) - MID_INSET
    front = float(shoulder[0]) - SHOULDER_SETBACK
    out = []
    if half > 0.0 and hi_l[0] > front:
        lo_c = np.array([front, max(lo_l[1], -half), lo_l[2]])
        hi_c = np.array([hi_l[0], min(hi_l[1], half), hi_l[2]])
        out.append((parent, _bounds_box("chest", lo_c, hi_c)))
    for other in model.config.manipulators:
        if other.name != m.name:
            link = robot.link_name[robot.joint_index[model.joint_names[model.group(other.group)[0]]]]
            out.append((link, _bounds_box(link, *_link_bounds(robot, model, q, link))))
    return out


def upper_arm_spheres(spheres: Sequence[tuple[str, FloatArray, float]]) -> list[tuple[str, FloatArray, float]]:
    """The spheres of ``arm_link_spheres`` on its first frame (the upper arm): those ``inner_obstacles`` keeps
    clear (the whole arm's against them cost 50 % more keyframe rows and ~0.5 s of keyframe CPU per plan)."""
    return [s for s in spheres if s[0] == spheres[0][0]] if spheres else []


def _link_bounds(robot, model, q: FloatArray, link: str, yaws: int = BOUND_YAWS) -> tuple[FloatArray, FloatArray]:
    """(lower (3,), upper (3,)) [m] in ``link``'s frame of a box holding the link: PyBullet's world-aligned
    bounding box, seen from the link's frame, holds the link at every base heading; at ``yaws`` headings
    over a quarter turn the boxes' intersection still holds it and is near the link's own extent (one
    heading alone: a link turned 45 degrees in the world gets a box twice its size, the PR2's raised left
    shoulder 0.62 m across, which the right upper arm could not pass)."""
    lo_all, hi_all = np.full(3, -np.inf), np.full(3, np.inf)
    yaw0 = float(q[2])
    for k in range(max(yaws, 1)):
        qk = np.array(q, float)
        qk[2] = yaw0 + 0.5 * np.pi * k / max(yaws, 1)
        robot.set_q(qk)
        lo, hi = (np.asarray(v, float)
                  for v in p.getAABB(robot.id, robot.link_index[link], physicsClientId=robot.client))
        T_link = model.fk(qk, link)
        corners = np.array([np.linalg.solve(T_link, np.r_[x, y, z, 1.0])[:3] for x in (lo[0], hi[0])
                            for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        lo_all, hi_all = np.maximum(lo_all, corners.min(axis=0)), np.minimum(hi_all, corners.max(axis=0))
    robot.set_q(q)
    return lo_all, hi_all


def _bounds_box(name: str, lo: FloatArray, hi: FloatArray) -> Box:
    T = np.eye(4)
    T[:3, 3] = (lo + hi) / 2
    size = hi - lo
    return Box(name, (float(size[0]), float(size[1]), float(size[2])), T, (0.0, 0.0, 0.0, 1.0))


def other_arm_obstacles(robot, model, q: FloatArray, manipulator: str | None = None) -> list[tuple[str, Box]]:
    """(link, box in that link's frame) of every other manipulator's links (arm and gripper) where ``q``
    holds them (the PR2's tucked left arm, which the right hand can otherwise sweep into): for the
    self-clearance rows (``self_clear``) of a plan that moves one arm only."""
    active = model.manipulator(manipulator).name
    out = []
    for m in model.config.manipulators:
        if m.name == active:
            continue
        joints = [model.joint_names[i] for i in model.group(m.group)]
        links = [robot.link_name[robot.joint_index[j]] for j in joints] + list(m.links)
        for link in dict.fromkeys(links):
            out.append((link, _bounds_box(link, *_link_bounds(robot, model, q, link))))
    return out


def self_clear(model, q_sym: ca.SX, spheres: list[tuple[str, FloatArray, float]], body: list[tuple[str, Box]],
               rows: Rows, margin: float = SELF_MARGIN) -> None:
    """The arm's spheres clear of the body's boxes (each box in its link's frame), at the configuration
    q_sym (``_self_rows``' rows)."""
    if not spheres or not body:
        return
    frames = _self_frames(spheres, body)
    Ts = model.casadi_fk(frames)(q_sym)
    Ts = dict(zip(frames, Ts if isinstance(Ts, (list, tuple)) else [Ts], strict=True))
    g, lower = _self_rows(Ts, spheres, body, margin)
    rows.add_all(g, lower, ca.inf)


def _self_frames(spheres: Sequence[tuple[str, FloatArray, float]], body: Sequence[tuple[str, Box]]) -> tuple[str, ...]:
    return tuple(dict.fromkeys([*(f for f, _ in body), *(f for f, _, _ in spheres)]))


def _self_rows(
    Ts: dict[str, ca.SX], spheres: Sequence[tuple[str, FloatArray, float]], body: Sequence[tuple[str, Box]],
    margin: float,
) -> tuple[ca.SX, FloatArray]:
    """The rows (sphere by sphere, each over every box) and their lower bounds, the frames at ``Ts`` (frame
    -> T_world_frame (4, 4)). Built box by box, all spheres at once (one product and one mapped
    ``box_sdf`` per box: ~0.1 s less per PR2 arm than sphere by box)."""
    centres = ca.horzcat(*(Ts[f][:3, :3] @ ca.DM(c) + Ts[f][:3, 3] for f, c, _ in spheres))  # (3, S) world
    n = len(spheres)
    per_box = []
    for bf, b in body:
        T_b = Ts[bf]
        pb = T_b[:3, :3].T @ (centres - ca.repmat(T_b[:3, 3], 1, n))  # (3, S) in the body link's frame
        Tinv = np.linalg.inv(b.T)
        per_box.append(box_sdf_columns(ca.DM(Tinv[:3, :3]) @ pb, Tinv[:3, 3], np.asarray(b.size) / 2))
    # (boxes, spheres) column-major: sphere by sphere, each over every box
    return ca.vec(ca.vertcat(*per_box)), np.repeat([r + margin for _, _, r in spheres], len(body))


class SelfRows(NamedTuple):
    """The self-clearance rows as a function of the transforms of ``frames``: ``rows(rs)`` at a robot's
    symbols (``RobotSymbols`` built with these frames: the rows read its forward kinematics, not a copy)."""

    fn: ca.Function  # T_world_frame (4, 4) per frame of ``frames`` -> the rows
    lower: FloatArray  # their lower bounds
    frames: tuple[str, ...]

    def rows(self, rs: RobotSymbols) -> ca.SX:
        return self.fn(*(rs.frame(f) for f in self.frames)) if self.frames else ca.SX(0, 1)


_SELF_ROWS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()  # model -> {arguments: self_rows_function's}
SELF_ROWS_KEPT = 16  # self-clearance functions kept per model (other arms' postures, bodies), least recent dropped


def _content_key(items: Sequence) -> bytes:
    """A key for a list of (link name, sphere centre, radius) or (link name, Box): their names and numbers."""
    out = []
    for item in items:
        for v in item if isinstance(item, tuple) else (item,):
            if isinstance(v, Box):
                out += [v.name.encode(), np.asarray(v.size, float).tobytes(), np.asarray(v.T, float).tobytes()]
            elif isinstance(v, str):
                out.append(v.encode())
            else:
                out.append(np.asarray(v, float).tobytes())
        out.append(b"|")
    return b"\0".join(out)


def self_rows_function(
    model, spheres: Sequence[tuple[str, FloatArray, float]], body: Sequence[tuple[str, Box]],
    margin: float = SELF_MARGIN,
) -> SelfRows:
    """``self_clear``'s rows as a ``SelfRows`` (the transforms in, the rows out). Built once per model and
    arguments (the ``SELF_ROWS_KEPT`` latest are kept), then shared (read-only): the keyframe NLP and level 3
    call it on their symbols' frames (an SX call inlines the rows on the forward kinematics the other rows
    read) instead of rebuilding the rows (PR2: ~20 ms per keyframe, ~90 ms per level 3). Before, the
    function took the joints and inlined forward kinematics of its own: a second copy of the arm's in every
    keyframe and level-3 checkpoint."""
    key = (_content_key(spheres), _content_key(body), margin)
    per_model = _SELF_ROWS.setdefault(model, {})
    out = per_model.pop(key, None)
    if out is None:
        if not spheres or not body:
            out = SelfRows(ca.Function("self_rows", [], [ca.SX(0, 1)]), np.zeros(0), ())
        else:
            frames = _self_frames(spheres, body)
            Ts = {f: ca.SX.sym(f, 4, 4) for f in frames}
            g, lower = _self_rows(Ts, spheres, body, margin)
            out = SelfRows(ca.Function("self_rows", [Ts[f] for f in frames], [g]), np.asarray(lower, float), frames)
    per_model[key] = out  # most recently used last; a long-running executive keeps the SELF_ROWS_KEPT latest
    while len(per_model) > SELF_ROWS_KEPT:
        del per_model[next(iter(per_model))]
    return out
