"""The robot as a PyBullet body: set a configuration, read link poses, query collisions.

The body is loaded from the same prepared URDF as the pinocchio model (planar base joints
included), with a fixed root: moving the base is moving three joints. Self-collision is on, minus
the allowed pairs: every link with its nearest ancestor that has collision geometry (parent/child
through geometry-less frames), plus the pairs listed in robot.toml. Collision queries run
PyBullet's narrow phase once and filter the robot's contacts by penetration depth.
"""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass

import numpy as np
import pybullet as p
from numpy.typing import ArrayLike, NDArray

from rlgp_exec.errors import ModelError
from rlgp_exec.robot.model import RobotModel
from rlgp_exec.robot.quiet import quiet_stdout

__all__ = ["Contact", "PyBulletRobot", "pose_to_matrix", "quat_xyzw"]

log = logging.getLogger(__name__)
# collision-filter bits for ``ignore_rigid_pairs``' groups: bit 0 is Bullet's default filter group and bit 1
# its static one (fixed bodies); a group mask keeps both, and the int32 mask's sign bit is left alone
FIRST_FILTER_BIT = 2
ALL_FILTER_BITS = 0x7FFFFFFF
FILTER_BITS = 31 - FIRST_FILTER_BIT
FloatArray = NDArray[np.float64]


def pose_to_matrix(position: Sequence[float], quaternion_xyzw: Sequence[float]) -> FloatArray:
    """T (4, 4) from a PyBullet position and (x, y, z, w) quaternion."""
    T = np.eye(4)
    T[:3, :3] = np.asarray(p.getMatrixFromQuaternion(quaternion_xyzw)).reshape(3, 3)
    T[:3, 3] = position
    return T


def quat_xyzw(R: FloatArray) -> list[float]:
    """PyBullet's (x, y, z, w) unit quaternion of a rotation matrix R (3, 3) (Shepperd's method: the
    largest of w, x, y, z is found first, so it is exact for every rotation; ~30x cheaper than scipy's
    ``Rotation.from_matrix``, which checks and orthogonalises its input, in the collision checker's loops)."""
    m00, m01, m02 = float(R[0, 0]), float(R[0, 1]), float(R[0, 2])
    m10, m11, m12 = float(R[1, 0]), float(R[1, 1]), float(R[1, 2])
    m20, m21, m22 = float(R[2, 0]), float(R[2, 1]), float(R[2, 2])
    tr = m00 + m11 + m22
    if tr >= max(m00, m11, m22):
        s = 2.0 * (1.0 + tr) ** 0.5
        q = [(m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s, 0.25 * s]
    elif m00 >= m11 and m00 >= m22:
        s = 2.0 * (1.0 + m00 - m11 - m22) ** 0.5
        q = [0.25 * s, (m01 + m10) / s, (m02 + m20) / s, (m21 - m12) / s]
    elif m11 >= m22:
        s = 2.0 * (1.0 + m11 - m00 - m22) ** 0.5
        q = [(m01 + m10) / s, 0.25 * s, (m12 + m21) / s, (m02 - m20) / s]
    else:
        s = 2.0 * (1.0 + m22 - m00 - m11) ** 0.5
        q = [(m02 + m20) / s, (m12 + m21) / s, 0.25 * s, (m10 - m01) / s]
    n = sum(v * v for v in q) ** 0.5
    return [v / n for v in q]


@dataclass(frozen=True)
class Contact:
    """A penetration between a robot link and another body (or another robot link)."""

    link: str
    other_body: int
    other_link: str  # link name for the robot itself, PyBullet link index as text otherwise
    distance: float  # [m], negative = penetration depth
    position: tuple[float, float, float]  # on the robot link, world frame [m]

    @property
    def is_self(self) -> bool:
        return self.other_link != "" and not self.other_link.lstrip("-").isdigit()


class PyBulletRobot:
    """A :class:`RobotModel` instantiated in a PyBullet client."""

    def __init__(self, model: RobotModel, client: int, *, collision_only: bool = False) -> None:
        """``collision_only``: a world that only checks collisions (no camera renders it) loads the robot
        without its visual meshes and without the links that carry no collision shape (``robot.urdf``:
        sensor and tool frames; ``pruned``); on the PR2 it loads in ~11 ms instead of ~21 and a joint
        reset takes ~29 us instead of ~62. ``carrier_index`` names a pruned link's PyBullet link."""
        self.model = model
        self.client = client
        self.collision_only = collision_only
        flags = p.URDF_USE_SELF_COLLISION | p.URDF_USE_SELF_COLLISION_EXCLUDE_PARENT
        path = model.urdf.collision_path if collision_only else model.urdf.pybullet_path
        if collision_only:
            flags |= p.URDF_IGNORE_VISUAL_SHAPES
        try:
            with quiet_stdout():
                self.id = p.loadURDF(str(path), useFixedBase=True, flags=flags, physicsClientId=client)
        except p.error as e:
            raise ModelError(f"{model.name}: PyBullet could not load {path}: {e}") from e
        self.link_index: dict[str, int] = {"world": -1}
        self.joint_index: dict[str, int] = {}
        self.parent_link: dict[str, str] = {}
        for i in range(p.getNumJoints(self.id, physicsClientId=client)):
            info = p.getJointInfo(self.id, i, physicsClientId=client)
            jname, lname = info[1].decode(), info[12].decode()
            self.joint_index[jname] = i
            self.link_index[lname] = i
            parent = info[16]
            parent_info = p.getJointInfo(self.id, parent, physicsClientId=client) if parent >= 0 else None
            self.parent_link[lname] = parent_info[12].decode() if parent_info else "world"
        self.link_name = {i: n for n, i in self.link_index.items()}
        pm = model.pin_model
        self._full_joints = [(self.joint_index[pm.names[j]], pm.joints[j].idx_q) for j in range(1, pm.njoints)]
        self._joint_ids = [ji for ji, _ in self._full_joints]
        self._q_ids = np.array([iq for _, iq in self._full_joints], dtype=int)
        self._last_qf: np.ndarray | None = None
        self.allowed_pairs = self._allowed_pairs()
        for a, b in self.allowed_pairs:
            ia, ib = self.link_index[a], self.link_index[b]
            p.setCollisionFilterPair(self.id, self.id, ia, ib, 0, physicsClientId=client)
        self._ignored_bodies: set[int] = set()
        self.set_q(model.home())

    # ------------------------------------------------------------------ set-up
    def _allowed_pairs(self) -> set[tuple[str, str]]:
        with_geom = self.model.urdf.links_with_collision
        pairs: set[tuple[str, str]] = set()
        for link in with_geom:
            anc = self.parent_link.get(link)
            while anc is not None and anc != "world" and anc not in with_geom:
                anc = self.parent_link.get(anc)
            if anc is not None and anc != "world":
                pairs.add(tuple(sorted((link, anc))))  # type: ignore[arg-type]
        for a, b in self.model.config.allowed_collisions:
            if not all(self._loaded(n, "robot.toml allowed pair") for n in (a, b)):
                continue  # a link left out of a collision-only world has no shape to collide
            pairs.add(tuple(sorted((a, b))))  # type: ignore[arg-type]
        return pairs

    def _loaded(self, link: str, what: str) -> bool:
        """Whether ``link`` is one of this body's links (False: left out of a collision-only world, which
        it cannot collide in); ModelError when the URDF has no such link."""
        if link in self.link_index:
            return True
        if self.collision_only and link in self.model.urdf.pruned:
            return False
        raise ModelError(f"{self.model.name}: {what} names unknown link {link!r}")

    def carrier_index(self, link: str) -> int:
        """The PyBullet link index ``link`` moves with: its own, or for a link a collision-only world left
        out (``robot.urdf``'s ``pruned``: on a fixed joint), its nearest ancestor's."""
        if self.collision_only:
            link = self.model.urdf.pruned.get(link, link)
        i = self.link_index.get(link)
        if i is None:
            raise ModelError(f"{self.model.name}: unknown link {link!r}")
        return i

    def ignore_floor(self, floor_body: int) -> None:
        """Never report contacts between ``floor_body`` and the links listed as floor_contact."""
        for name in self.model.config.floor_contact:
            if self._loaded(name, "floor_contact"):
                p.setCollisionFilterPair(self.id, floor_body, self.link_index[name], -1, 0,
                                         physicsClientId=self.client)

    def ignore_rigid_pairs(self, qs: ArrayLike, tolerance: float = 1e-3) -> bool:
        """Stop checking the pairs of links that no joint moving across the configurations ``qs`` (m, nq)
        (linear between them: a replay's waypoints) moves relative to each other: their relative pose,
        hence their contact, stays what it is at qs[0], where the robot is set. One collision-filter
        group per set of links such a joint does not separate (a pair in one group never collides; by
        group and mask, ~0.4 ms, where a filter per pair costs ~0.2 ms each). Refused (False, nothing
        changed) when such a pair penetrates deeper than ``tolerance`` [m] at qs[0] (checked as ever,
        it then counts) or there are more groups than filter bits."""
        qs = np.atleast_2d(np.asarray(qs, float))
        full = np.array([self.model.full_q(q)[self._q_ids] for q in qs])
        moving = {self._joint_ids[i] for i in np.flatnonzero(np.ptp(full, axis=0) > 0.0)}
        n_links = p.getNumJoints(self.id, physicsClientId=self.client)
        parent = {i: p.getJointInfo(self.id, i, physicsClientId=self.client)[16] for i in range(n_links)}

        def rigid_root(link: int) -> int:  # the link's nearest ancestor (or itself) a moving joint carries
            while link != -1 and link not in moving:
                link = parent[link]
            return link

        group = {link: rigid_root(link) for link in range(-1, n_links)}
        roots = sorted(set(group.values()))
        if len(roots) > FILTER_BITS:
            return False
        self.set_q(qs[0])
        p.performCollisionDetection(physicsClientId=self.client)
        for c in p.getContactPoints(bodyA=self.id, bodyB=self.id, physicsClientId=self.client):
            if group[c[3]] == group[c[4]] and c[8] < -tolerance:
                return False
        bit = {root: 1 << (k + FIRST_FILTER_BIT) for k, root in enumerate(roots)}
        for link, root in group.items():  # bits 0 and 1: Bullet's default and static bodies, still met
            p.setCollisionFilterGroupMask(self.id, link, bit[root], ALL_FILTER_BITS & ~bit[root],
                                          physicsClientId=self.client)
        return True

    def ignore_body(self, body: int, ignore: bool = True) -> None:
        """Exclude (or re-include) a body from :meth:`contacts` (e.g. an object held in the hand)."""
        if ignore:
            self._ignored_bodies.add(body)
        else:
            self._ignored_bodies.discard(body)

    # ------------------------------------------------------------------ state
    def set_q(self, q: ArrayLike, only_changed: bool = False) -> None:
        """Teleport the robot to q (nq,) (mimic and locked joints included).

        ``only_changed`` resets just the joints that differ from the last ``set_q`` (several times faster
        for a sweep along an edge); valid only while nothing else moves the robot (no physics steps)."""
        qf = self.model.full_q(q)[self._q_ids]
        if only_changed and self._last_qf is not None:
            idx = np.flatnonzero(qf != self._last_qf)
            ids = [self._joint_ids[i] for i in idx]
        else:
            idx, ids = np.arange(qf.size), self._joint_ids
        # one batched call (a per-joint resetJointState loop costs ~1 ms on the PR2's 80+ joints)
        if ids:
            p.resetJointStatesMultiDof(self.id, ids, qf[idx].reshape(-1, 1).tolist(), physicsClientId=self.client)
        self._last_qf = qf

    def get_q(self) -> FloatArray:
        """The current q (nq,) read back from the joints."""
        q = np.empty(self.model.nq)
        for i, n in enumerate(self.model.joint_names):
            q[i] = p.getJointState(self.id, self.joint_index[n], physicsClientId=self.client)[0]
        return self.model.limits.wrap(q)

    def link_pose(self, link: str) -> FloatArray:
        """T_world_link (4, 4): the URDF link frame."""
        i = self.link_index.get(link)
        if i is None:
            raise ModelError(f"{self.model.name}: unknown link {link!r}")
        if i < 0:
            return np.eye(4)
        st = p.getLinkState(self.id, i, computeForwardKinematics=True, physicsClientId=self.client)
        return pose_to_matrix(st[4], st[5])

    # ------------------------------------------------------------------ collisions
    def contacts(self, tolerance: float = 1e-3, refresh: bool = True) -> list[Contact]:
        """Penetrations deeper than ``tolerance`` [m] between the robot and anything (itself included)."""
        if refresh:
            p.performCollisionDetection(physicsClientId=self.client)
        out: list[Contact] = []
        for c in p.getContactPoints(bodyA=self.id, physicsClientId=self.client):
            body_b, link_a, link_b, dist = c[2], c[3], c[4], c[8]
            if dist >= -tolerance or body_b in self._ignored_bodies:
                continue
            other = self.link_name.get(link_b, str(link_b)) if body_b == self.id else str(link_b)
            out.append(Contact(self.link_name.get(link_a, str(link_a)), body_b, other, float(dist), tuple(c[5])))
        return out

    def in_collision(self, q: ArrayLike | None = None, tolerance: float = 1e-3, only_changed: bool = False) -> bool:
        """True when the robot (at q, if given) penetrates the world or itself by more than ``tolerance``
        [m]; a negative tolerance demands that much clearance (PyBullet reports contacts up to ~2 cm apart)."""
        if q is not None:
            self.set_q(q, only_changed)
        return bool(self.contacts(tolerance))

    def clearance(self, bodies: Iterable[int], max_distance: float = 0.5) -> float:
        """Smallest distance [m] between the robot and ``bodies`` (capped at ``max_distance``)."""
        best = max_distance
        for b in bodies:
            for c in p.getClosestPoints(self.id, b, max_distance, physicsClientId=self.client):
                best = min(best, float(c[8]))
        return best
