"""What a robot's open gripper can hold, probed once per robot in PyBullet from its own collision shapes.

A top grasp puts the tool point ``GRASP_DEPTH`` below the object's top (at most half its height,
``nlp.factors.grasp_point``). Two numbers decide whether an object can be held that way at all:

* ``open_width_m``: the widest square footprint [m] a probe box, top at the grasp depth and reaching
  far ahead of the hand, can have between the open fingers without touching them (PyBullet's contact
  distance, the replay's measure, so the convex hulls' margins count);
* ``tip_reach_m``: how far [m] the open fingers reach ahead of the tool point along the approach axis
  (a wide plate ahead of the hand, moved until it touches them): the support surface under a held
  object must stay further than this below the tool point, or the fingers meet it.

The fingers are the links whose pose in the tool frame changes between the gripper's open and closed
positions (``robot.toml``), so the same probe serves every robot.
"""

from __future__ import annotations

import functools
import logging
from typing import NamedTuple

import numpy as np
import pybullet as p

from rlgp_exec.planning.margins import RELEASE_CLEARANCE
from rlgp_exec.planning.nlp.factors import GRASP_DEPTH
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.pybullet_body import PyBulletRobot, pose_to_matrix, quat_xyzw

__all__ = ["GripperLimits", "gripper_limits", "min_graspable_height"]

log = logging.getLogger(__name__)

_PROBE_LONG = 0.3  # [m] the probes' extent where only their near face matters
_BISECTIONS = 24  # halvings of the probes' search interval: well below a millimetre


class GripperLimits(NamedTuple):
    robot: str
    open_width_m: float  # widest square footprint clear of the open fingers at the grasp depth [m]
    tip_reach_m: float  # the open fingers' reach ahead of the tool point along the approach axis [m]

    @property
    def max_width_m(self) -> float:
        """Widest footprint [m] the hand can close round and let go of with ``RELEASE_CLEARANCE`` each side."""
        return self.open_width_m - 2 * RELEASE_CLEARANCE


def min_graspable_height(limits: GripperLimits) -> float:
    """Lowest object [m] whose support stays ``RELEASE_CLEARANCE`` beyond the open fingertips when the tool point
    is at the grasp depth (``GRASP_DEPTH`` below the top, at most half the height)."""
    need = max(limits.tip_reach_m + RELEASE_CLEARANCE, 0.0)  # the tool point's least height above the support
    return 2 * need if need <= GRASP_DEPTH else need + GRASP_DEPTH


def _finger_links(robot: PyBulletRobot, model, q_open: np.ndarray, q_closed: np.ndarray, tool: str) -> list[int]:
    def poses(q: np.ndarray) -> dict[int, np.ndarray]:
        robot.set_q(q)
        T_tool = model.fk(q, tool)
        out = {}
        for i in robot.link_index.values():
            if i < 0:
                continue
            st = p.getLinkState(robot.id, i, computeForwardKinematics=True, physicsClientId=robot.client)
            out[i] = np.linalg.solve(T_tool, pose_to_matrix(st[4], st[5]))
        return out

    closed, opened = poses(q_closed), poses(q_open)
    moving = [i for i in opened if not np.allclose(opened[i], closed[i], atol=1e-6)]
    return [i for i in moving if p.getCollisionShapeData(robot.id, i, physicsClientId=robot.client)]


def _bisect(touches, lo: float, hi: float) -> float:
    """The largest x in [lo, hi] with ``touches(x)`` false (``touches`` monotone: false below, true above)."""
    if touches(lo):
        return lo
    if not touches(hi):
        return hi
    for _ in range(_BISECTIONS):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if touches(mid) else (mid, hi)
    return lo


@functools.cache
def gripper_limits(robot_name: str) -> GripperLimits:
    """The first manipulator's open-gripper limits for ``robot_name`` (see the module), probed once."""
    model = load_robot(robot_name)
    man = model.manipulator()
    grip = list(model.group(man.gripper))
    q_open, q_closed = model.home(), model.home()
    q_open[grip], q_closed[grip] = man.open, man.closed
    a, c = np.asarray(man.approach, float), np.asarray(man.closing, float)
    b = np.cross(c, a)  # [b, c, a] right-handed
    client = p.connect(p.DIRECT)
    try:
        robot = PyBulletRobot(model, client, collision_only=True)
        fingers = _finger_links(robot, model, q_open, q_closed, man.tool_frame)
        robot.set_q(q_open)
        T_tool = model.fk(q_open, man.tool_frame)
        R_box = np.column_stack([b, c, a])  # box axes in the tool frame: x along b, y closing, z approach
        R_world = T_tool[:3, :3] @ R_box

        def touches(size: tuple[float, float, float], centre_tool: np.ndarray) -> bool:
            shape = p.createCollisionShape(p.GEOM_BOX, halfExtents=[s / 2 for s in size], physicsClientId=client)
            pos = (T_tool @ np.r_[centre_tool, 1.0])[:3]
            body = p.createMultiBody(0.0, shape, -1, pos.tolist(), quat_xyzw(R_world), physicsClientId=client)
            try:
                return any(pt[8] < 0.0 for i in fingers
                           for pt in p.getClosestPoints(robot.id, body, 0.0, linkIndexA=i, physicsClientId=client))
            finally:
                p.removeBody(body, physicsClientId=client)

        def wide(w: float) -> bool:  # a w x w column, top GRASP_DEPTH behind the tool point
            return touches((w, w, _PROBE_LONG), a * (_PROBE_LONG / 2 - GRASP_DEPTH))

        def slab(d: float) -> bool:  # a wide slab ahead of the hand, its near face d ahead of the tool point
            return touches((2 * _PROBE_LONG, 2 * _PROBE_LONG, _PROBE_LONG), a * (d + _PROBE_LONG / 2))

        width = _bisect(wide, 1e-4, 2 * _PROBE_LONG)
        reach = -_bisect(lambda x: slab(-x), -_PROBE_LONG, _PROBE_LONG)
    finally:
        p.disconnect(client)
    limits = GripperLimits(robot_name, round(width, 5), round(reach, 5))
    log.debug("%s: open gripper %.4f m wide at the grasp depth, fingertips %.4f m ahead of the tool point",
              robot_name, limits.open_width_m, limits.tip_reach_m)
    return limits
