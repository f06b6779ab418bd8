"""Conservative advancement along a straight edge, measured lazily link by link (``reach.checker.WorldChecker``).

Each (robot link, obstacle body) pair, and each (held object, obstacle body) pair, is an *entry* with a
*horizon*: the edge parameter s up to which its last measurement certifies it. Measured at s_m at
distance d [m], with ``bound`` [m per unit s] on how far any of its points moves along the edge, an
entry keeps at least the clearance c until H = s_m + (d - c) / bound. The sweep samples at the
smallest horizon; there it re-measures the entries that expire (H <= s) and those whose certified
distance c + (H - s) bound is within MIN_ADVANCE of the clearance (as a sweep measuring everything
would see them), then every entry whose horizon lies below the smallest re-measured one, until none
does. The next sample, the smallest horizon, is then the one a sweep measuring every link at every
sample would take (a re-measurement never lowers a horizon), but only the few entries that limit it
pay for a PyBullet query (~3 us per link against ~130 us per robot-body query). The verdict is exact
for the continuous motion, as before: between samples no entry can come closer than c.

Distances are measured only as far as they matter (at most LOOKAHEAD): an entry farther away than its
motion over the rest of the edge, plus c, is certified to s = 1 by that cap.

An edge that moves the base is swept in the base's frame at q1 (``_Obstacles``): the robot's base
joints stay at q1's and the obstacle bodies a sample measures are moved by the inverse of the base's
motion instead (distances do not change under a rigid motion of everything). Setting the base joints
moves every robot link in PyBullet (~80-110 us); an arm joint moves a few (~25 us), an obstacle ~2 us.
The obstacles are put back before the sweep returns.
"""

from __future__ import annotations

import math
from typing import Protocol

import numpy as np
import pybullet as p

from rlgp_exec.planning import budget
from rlgp_exec.robot.model import FloatArray

__all__ = ["SweptWorld", "planar_base", "sweep"]


class _Robot(Protocol):
    id: int

    def set_q(self, q: FloatArray, only_changed: bool = ...) -> None: ...


class SweptWorld(Protocol):
    """What a sweep reads and moves of its checker (``reach.checker.WorldChecker``)."""

    @property
    def robot(self) -> _Robot: ...

    client: int
    clearance: float
    calls: int
    shaped_rows: np.ndarray  # (m,) PyBullet link rows (link index + 1) of the links with collision shapes
    row_entry: np.ndarray  # a link row's index into shaped_rows (-1: none)
    finger_links: frozenset[int]
    planar_base: bool
    attached: tuple[int, FloatArray, float] | None
    knob: int | None

    def place_held(self, q: FloatArray) -> None: ...

    def self_collision(self, q: FloatArray) -> bool: ...

LOOKAHEAD = 0.5  # [m] distances are measured up to this far (the checker's)
MIN_ADVANCE = 1e-3  # [m] closer than the clearance + this (before the end) counts as a collision


def planar_base(body: int, client: int, names: tuple[str, ...] | list[str]) -> bool:
    """True when q's first three joints move the robot as the planar pose (x, y, yaw) in the world frame
    (root at the world's origin, z up; PyBullet's first three joints q's, along world x, y and about z,
    their frames not offset): ``sweep`` then moves the obstacles instead of the base."""
    pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=client)
    if not (np.allclose(pos[:2], 0.0, atol=1e-12) and np.allclose(orn, [0, 0, 0, 1], atol=1e-12)):
        return False
    for i, (kind, axis) in enumerate(((p.JOINT_PRISMATIC, (1, 0, 0)), (p.JOINT_PRISMATIC, (0, 1, 0)),
                                      (p.JOINT_REVOLUTE, (0, 0, 1)))):
        info = p.getJointInfo(body, i, physicsClientId=client)
        same = info[1].decode() == names[i] and info[2] == kind and np.allclose(info[13], axis, atol=1e-12)
        unmoved = np.allclose(info[14][:2], 0.0, atol=1e-12) and np.allclose(info[15], [0, 0, 0, 1], atol=1e-12)
        if not (same and unmoved):
            return False
    return True


class _Obstacles:
    """The obstacle bodies of a sweep, each moved (lazily, when a sample measures it) so that the robot,
    its base held at q1's pose, sees them as it would with its base at the sample's (world frame: z up,
    the base a planar x, y, yaw pose)."""

    def __init__(self, client: int, bodies: list[int], q1: FloatArray, dq: FloatArray, planar: bool) -> None:
        """``planar``: q's first three joints are the base's world pose (``WorldChecker.planar_base``);
        otherwise (or when the edge does not move the base) nothing is moved."""
        self.client = client
        self.active = planar and bool(np.any(dq[:3] != 0.0))
        self.x1, self.y1 = float(q1[0]), float(q1[1])
        self.q1, self.dq = q1, dq
        self.home = {b: p.getBasePositionAndOrientation(b, physicsClientId=client) for b in bodies if self.active}
        self.at = dict.fromkeys(self.home, 0.0)  # body -> the s it is placed for (0: where it stands)

    def robot_q(self, s: float) -> FloatArray:
        """The robot's configuration at s: the edge's, the base at q1 while the obstacles move."""
        q = self.q1 + s * self.dq
        if self.active:
            q[:3] = self.q1[:3]
        return q

    def place(self, body: int, s: float) -> None:
        """Body where the base at q1 sees it when the base is at s: p' = Rz(phi) (p - t_s) + t_1 with
        phi = yaw_1 - yaw_s, t the base's position; orientation Rz(phi) times its own."""
        if not self.active or self.at[body] == s:
            return
        (px, py, pz), (qx, qy, qz, qw) = self.home[body]
        phi = -s * float(self.dq[2])
        cp, sp = math.cos(phi), math.sin(phi)
        dx, dy = px - (self.x1 + s * float(self.dq[0])), py - (self.y1 + s * float(self.dq[1]))
        hz, hw = math.sin(phi / 2), math.cos(phi / 2)  # (0, 0, hz, hw) * (qx, qy, qz, qw)
        quat = (hw * qx - hz * qy, hw * qy + hz * qx, hw * qz + hz * qw, hw * qw - hz * qz)
        pos = (cp * dx - sp * dy + self.x1, sp * dx + cp * dy + self.y1, pz)
        p.resetBasePositionAndOrientation(body, pos, quat, physicsClientId=self.client)
        self.at[body] = s

    def restore(self) -> None:
        for body, s in self.at.items():
            if s != 0.0:
                pos, quat = self.home[body]
                p.resetBasePositionAndOrientation(body, pos, quat, physicsClientId=self.client)
                self.at[body] = 0.0


def sweep(
    ch: SweptWorld,
    q1: FloatArray,
    dq: FloatArray,
    pairs: list[tuple[int, int]],
    links_bound: FloatArray,
    held_bound: float,
    n_self: int,
) -> bool:
    """True when the motion q1 -> q1 + dq comes within ``ch.clearance`` of the obstacles of ``pairs``
    ((moving body, obstacle body): the robot's, or the held object's), or, with ``n_self`` > 0,
    self-collides at one of its samples at least 1 / n_self apart in s (and at its end).
    ``links_bound`` (rows: PyBullet link index + 1) and ``held_bound`` bound the motion [m] of any
    point of each robot link and of the held object over the whole edge."""
    rows = ch.shaped_rows  # (m,) rows of the links with collision shapes
    robot_obst = [b for a, b in pairs if a == ch.robot.id]
    held_obst = [b for a, b in pairs if a != ch.robot.id]
    # entries: robot links (row-major over rows x robot_obst), then the held object's
    bound = np.concatenate([np.repeat(links_bound[rows], len(robot_obst)), np.full(len(held_obst), held_bound)])
    moving = bound > 0.0
    with np.errstate(divide="ignore"):
        per_m = np.where(moving, 1.0 / np.where(moving, bound, 1.0), np.inf)  # [s per m]
    tol = np.where(moving, MIN_ADVANCE * np.where(moving, per_m, 0.0), 0.0)  # [s] MIN_ADVANCE per entry
    fingers = np.isin(rows - 1, list(ch.finger_links))
    obstacles = _Obstacles(ch.client, list(dict.fromkeys(robot_obst + held_obst)), q1, dq, ch.planar_base)
    try:
        return _advance(ch, obstacles, robot_obst, held_obst, bound, per_m, tol, fingers, n_self)
    finally:
        obstacles.restore()


def _advance(
    ch: SweptWorld,
    obstacles: _Obstacles,
    robot_obst: list[int],
    held_obst: list[int],
    bound: FloatArray,
    per_m: FloatArray,
    tol: FloatArray,
    fingers: np.ndarray,
    n_self: int,
) -> bool:
    """``sweep``'s loop over the samples (module docstring)."""
    c, client, robot = ch.clearance, ch.client, ch.robot.id
    rows = ch.shaped_rows
    held_body = ch.attached[0] if ch.attached is not None and held_obst else None
    nk, nh = len(robot_obst), len(held_obst)
    nr = rows.size * nk
    # per entry, as Python values for the per-sample loop: obstacle body, robot link (PyBullet index),
    # whether the fingers may touch that body's drawer, motion bound [m], [s per m]
    body_of = [robot_obst[e % nk] for e in range(nr)] + held_obst
    link_of = [int(rows[e // nk]) - 1 for e in range(nr)]
    knobbed = [bool(fingers[e // nk]) and robot_obst[e % nk] == ch.knob for e in range(nr)]
    bound_of, per_m_of = bound.tolist(), per_m.tolist()
    lo_upto = c + MIN_ADVANCE
    horizon = np.full(nr + nh, -np.inf)
    s, last_self, first = 0.0, -1.0, True
    while True:
        q = obstacles.robot_q(s)
        ch.calls += 1
        if not ch.calls & 15:  # a far motion takes millions of samples
            budget.check()
        ch.robot.set_q(q, only_changed=True)
        held_placed = False
        margin = MIN_ADVANCE * (s < 1.0)
        if first:  # every link of a body in one query each
            upto = min(LOOKAHEAD, c + max(MIN_ADVANCE, float(bound.max(initial=0.0))))
            dist = np.full(nr + nh, upto)
            for k, b in enumerate(robot_obst):
                for pt in p.getClosestPoints(robot, b, upto, physicsClientId=client):
                    if b == ch.knob and pt[3] in ch.finger_links and pt[4] == 0:
                        continue  # the fingers round the knob
                    e = ch.row_entry[pt[3] + 1] * nk + k
                    dist[e] = min(dist[e], float(pt[8]))
            if nh:
                ch.place_held(q)
                held_placed = True
                for k, b in enumerate(held_obst):
                    for pt in p.getClosestPoints(held_body, b, upto, physicsClientId=client):
                        dist[nr + k] = min(dist[nr + k], float(pt[8]))
            if float(dist.min(initial=LOOKAHEAD)) < c + margin:
                return True
            horizon = np.where(bound > 0.0, s + (dist - c) * per_m, np.inf)
            h_min = float(horizon.min(initial=np.inf))
            first = False
        else:
            # expired, or certified too close; then the stale ones below the smallest fresh horizon
            todo = np.flatnonzero(horizon < (s + tol if s < 1.0 else s)).tolist()
            fresh_min = h_min = np.inf
            rest, too_close = 1.0 - s, c + margin
            while todo:
                for e in todo:
                    upto = c + rest * bound_of[e]
                    upto = LOOKAHEAD if upto > LOOKAHEAD else (lo_upto if upto < lo_upto else upto)
                    b = body_of[e]
                    if obstacles.at.get(b, s) != s:
                        obstacles.place(b, s)
                    if e < nr:
                        pts = p.getClosestPoints(robot, b, upto, linkIndexA=link_of[e], physicsClientId=client)
                        if knobbed[e]:
                            pts = [pt for pt in pts if pt[4] != 0]  # the fingers round the knob
                    else:
                        if not held_placed:
                            ch.place_held(q)
                            held_placed = True
                        pts = p.getClosestPoints(held_body, b, upto, physicsClientId=client)
                    d = upto
                    for pt in pts:
                        if pt[8] < d:
                            d = pt[8]
                    if d < too_close:
                        return True
                    h = s + (d - c) * per_m_of[e]
                    horizon[e] = h
                    if h < fresh_min:
                        fresh_min = h
                h_min = float(horizon.min())
                todo = np.flatnonzero(horizon < fresh_min).tolist() if h_min < fresh_min else []
            if fresh_min == np.inf:  # nothing measured (s bumped past every horizon's start)
                h_min = float(horizon.min(initial=np.inf))
        if n_self and (s - last_self >= 1.0 / n_self or s >= 1.0):
            if ch.self_collision(q):
                return True
            last_self = s
        if s >= 1.0:
            return False
        s = min(1.0, max(h_min, s + 1e-6))
