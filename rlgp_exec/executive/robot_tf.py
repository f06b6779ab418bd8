"""The robot as a viewer draws it: its URDF (``/robot_description``) and its links' transforms (TF).

The description is the robot's own URDF, without the planar base ``world -> base_x_link -> base_y_link``
the planners add: odometry gives ``world -> <root link>``, as on a real robot. Link transforms come
from forward kinematics at each joint state: for every joint, ``T_parent_child`` between its two links
(moving joints, mimic joints included, at each state; fixed joints once, as static transforms).
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from collections.abc import Sequence
from functools import cached_property
from pathlib import Path

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike

from rlgp_exec.executive.ros_messages import WORLD
from rlgp_exec.robot.config import BASE_JOINTS
from rlgp_exec.robot.model import FloatArray, RobotModel

__all__ = ["RobotTf"]

_PLANAR_LINKS = ("world", "base_x_link", "base_y_link")


def _inverse(T: FloatArray) -> FloatArray:
    """Inverses (N, 4, 4) of rigid transforms (N, 4, 4)."""
    R = np.transpose(T[:, :3, :3], (0, 2, 1))
    out = np.zeros_like(T)
    out[:, :3, :3] = R
    out[:, :3, 3] = -np.einsum("nij,nj->ni", R, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


class RobotTf:
    """``model``'s URDF text and link transforms (module docstring)."""

    def __init__(self, model: RobotModel) -> None:
        self.model = model
        self.root = model.urdf.root_link
        joints = [j for j in model.urdf.joints if j.name not in BASE_JOINTS]
        self.moving = tuple((j.parent, j.child) for j in joints if j.type != "fixed")
        self.fixed = tuple((j.parent, j.child) for j in joints if j.type == "fixed")
        links = sorted({lk for pair in self.moving + self.fixed for lk in pair} | {self.root})
        self.links = tuple(links)
        self._slot = {lk: i for i, lk in enumerate(links)}
        self._frame_ids = [model.frame_id(lk) for lk in links]
        self._data = model.pin_model.createData()  # its own: the model's is used by other threads
        self._index: dict[tuple[str, ...], np.ndarray] = {}

    @cached_property
    def description(self) -> str:
        """The URDF text without the planar base; mesh paths as ``file://`` URLs (a viewer's loader)."""
        robot = ET.fromstring(Path(self.model.urdf.pybullet_path).read_text())
        for el in list(robot):
            if (el.tag == "link" and el.get("name") in _PLANAR_LINKS) or (
                el.tag == "joint" and el.get("name") in BASE_JOINTS
            ):
                robot.remove(el)
        for mesh in robot.iter("mesh"):
            name = mesh.get("filename", "")
            if name.startswith("/"):
                mesh.set("filename", "file://" + name)
        return ET.tostring(robot, encoding="unicode")

    def q(self, base: ArrayLike, names: Sequence[str], values: ArrayLike) -> FloatArray:
        """The model's q (nq,) from a base pose (x, y, yaw) and joint values (joints the model lacks: left out)."""
        key = tuple(names)
        idx = self._index.get(key)
        if idx is None:
            idx = np.array([self.model.index(n) if n in self.model.joint_names else -1 for n in key], dtype=int)
            self._index[key] = idx
        q = self.model.home(tuple(np.asarray(base, dtype=float)))
        vals = np.asarray(values, dtype=float)
        q[idx[idx >= 0]] = vals[idx >= 0]
        return q

    def _poses(self, q: FloatArray) -> FloatArray:
        """T_world_link (N, 4, 4) of every link of ``links`` at q (nq,)."""
        pin.framesForwardKinematics(self.model.pin_model, self._data, self.model.full_q(q))
        oMf = self._data.oMf
        return np.stack([oMf[i].homogeneous for i in self._frame_ids])

    def positions(self, qs: FloatArray, frame: str) -> FloatArray:
        """The origin (n, 3) in ``world`` of ``frame`` at each configuration of ``qs`` (n, nq)."""
        fid = self.model.frame_id(frame)
        out = np.empty((len(qs), 3))
        for k, q in enumerate(qs):
            pin.framesForwardKinematics(self.model.pin_model, self._data, self.model.full_q(q))
            out[k] = self._data.oMf[fid].translation
        return out

    def _relative(self, T_world: FloatArray, pairs: Sequence[tuple[str, str]]) -> list[tuple[str, str, FloatArray]]:
        if not pairs:
            return []
        parents = T_world[[self._slot[p] for p, _ in pairs]]
        children = T_world[[self._slot[c] for _, c in pairs]]
        rel = np.einsum("nij,njk->nik", _inverse(parents), children)
        return [(p, c, rel[i]) for i, (p, c) in enumerate(pairs)]

    def transforms(self, q: FloatArray) -> list[tuple[str, str, FloatArray]]:
        """``(world, root, T_world_root)`` and ``(parent, child, T_parent_child)`` of every moving joint at
        ``q`` (nq,): the whole robot's TF, one kinematics pass."""
        T = self._poses(q)
        return [(WORLD, self.root, T[self._slot[self.root]]), *self._relative(T, self.moving)]

    def static_transforms(self, q: FloatArray | None = None) -> list[tuple[str, str, FloatArray]]:
        """``(parent, child, T_parent_child)`` of every fixed joint (they do not depend on ``q``)."""
        return self._relative(self._poses(self.model.home() if q is None else q), self.fixed)

