"""The open hand in the keyframe NLP: spheres along the fingers, fixed in the tool frame.

The arm spheres of ``nlp.factors`` stop at the tool point; an open gripper reaches further sideways
(the HSR's open fingers span about 25 cm), which is what hits a wall next to an object or the carcass
above a knob. :func:`finger_spheres` reads the finger links' box collision shapes in PyBullet at the
nominal configuration (the hand open) and puts three spheres along each box's long axis, in the tool
frame; :func:`points_clear` keeps them clear of boxes. Links whose shapes are meshes get none (their
hull is not a box), so for them the NLP stays as it was and the PyBullet check decides.

Self-collision proxy (:func:`self_clear`): spheres on the arm links' cylinders and boxes kept clear of
the base's cylinder (the HSR's arm, low and level, otherwise rests on its base); PR2's meshes give none.
"""

from __future__ import annotations

import casadi as ca
import numpy as np
import pybullet as p

from rlgp_exec.planning.nlp.factors import Rows
from rlgp_exec.reach.ik import box_sdf
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.robot.pybullet_body import pose_to_matrix
from rlgp_exec.scene.geometry import Box

__all__ = ["arm_link_spheres", "base_obstacles", "finger_spheres", "points_clear", "self_clear"]


def finger_spheres(robot, model, q: FloatArray) -> list[tuple[FloatArray, float]]:
    """(centre in the tool frame (3,) [m], radius [m]) spheres on the finger links' box shapes at ``q``."""
    manip = model.manipulator()
    robot.set_q(q)
    T_tool = model.fk(q, manip.tool_frame)
    out: list[tuple[FloatArray, float]] = []
    for name in manip.links:
        if "finger" not in name:
            continue
        i = robot.link_index[name]
        st = p.getLinkState(robot.id, i, computeForwardKinematics=True, physicsClientId=robot.client)
        T_com = pose_to_matrix(st[0], st[1])
        for d in p.getCollisionShapeData(robot.id, i, physicsClientId=robot.client):
            if d[2] != p.GEOM_BOX:
                continue
            size = np.asarray(d[3], float)
            T_shape = T_com @ pose_to_matrix(d[5], d[6])
            long = int(np.argmax(size))
            r = float(np.sort(size)[1]) / 2
            for s in (-0.5, 0.0, 0.5):
                local = np.zeros(3)
                local[long] = s * (size[long] - 2 * r)
                pw = T_shape @ np.r_[local, 1.0]
                out.append((np.linalg.solve(T_tool, pw)[:3], r))
    return out


def points_clear(T_tool: ca.SX, spheres: list[tuple[FloatArray, float]], boxes: list[Box], rows: Rows) -> None:
    """Every sphere (tool frame) at least its radius from every box."""
    for b in boxes:
        Tinv = np.linalg.inv(b.T)
        half = np.asarray(b.size) / 2
        for c, r in spheres:
            pw = T_tool[:3, :3] @ ca.DM(c) + T_tool[:3, 3]
            pl = ca.DM(Tinv[:3, :3]) @ pw + ca.DM(Tinv[:3, 3])
            rows.add(box_sdf(pl, half), r, ca.inf)


def _urdf_cylinders(model) -> dict[str, list[tuple[FloatArray, float, float]]]:
    """link -> [(T_link_cylinder (4, 4), radius, length)] from the URDF's collision cylinders."""
    import xml.etree.ElementTree as ET

    from scipy.spatial.transform import Rotation

    from rlgp_exec.robot.urdf import prepare_urdf

    root = ET.fromstring(prepare_urdf(model.config).pinocchio_xml)
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
            out.setdefault(str(link.get("name")), []).append((T, float(cyl.get("radius")), float(cyl.get("length"))))
    return out


def arm_link_spheres(model, manipulator: str | None = None) -> list[tuple[str, FloatArray, float]]:
    """(link frame, centre in that frame (3,), radius [m]) spheres on the arm links' collision cylinders
    (three per cylinder, on its axis), the lift's link excluded (it rides the body)."""
    m = model.manipulator(manipulator)
    cyl = _urdf_cylinders(model)
    out: list[tuple[str, FloatArray, float]] = []
    for j in [model.joint_names[i] for i in model.group(m.group)][1:]:
        link = j.removesuffix("_joint") + "_link"
        for T, r, length in cyl.get(link, []):
            for s in (-0.5, 0.0, 0.5):
                out.append((link, (T @ np.r_[0.0, 0.0, s * max(length - 2 * r, 0.0), 1.0])[:3], r))
    return out


def base_obstacles(model) -> list[Box]:
    """The base link's collision cylinders as boxes in the base link's frame (the body column is left
    out: the arm rides along it)."""
    return [
        Box("base", (2 * r, 2 * r, length), T, (0.0, 0.0, 0.0, 1.0))
        for T, r, length in _urdf_cylinders(model).get("base_link", [])
    ]


def self_clear(model, q_sym: ca.SX, spheres: list[tuple[str, FloatArray, float]], base: list[Box], rows: Rows,
               margin: float = 0.01) -> None:
    """The arm's link spheres clear of the base's shapes (both in the base link's frame)."""
    if not spheres or not base:
        return
    frames = tuple(dict.fromkeys(["base_link", *(f for f, _, _ in spheres)]))
    Ts = model.casadi_fk(frames)(q_sym)
    Ts = dict(zip(frames, Ts if isinstance(Ts, (list, tuple)) else [Ts], strict=True))
    T_b = Ts["base_link"]
    for f, c, r in spheres:
        pw = Ts[f][:3, :3] @ ca.DM(c) + Ts[f][:3, 3]
        pb = T_b[:3, :3].T @ (pw - T_b[:3, 3])
        for b in base:
            Tinv = np.linalg.inv(b.T)
            pl = ca.DM(Tinv[:3, :3]) @ pb + ca.DM(Tinv[:3, 3])
            rows.add(box_sdf(pl, np.asarray(b.size) / 2), r + margin, ca.inf)
