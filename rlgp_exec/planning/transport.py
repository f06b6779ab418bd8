"""Chains of straight, exactly checked motions between two configurations of a candidate plan: the
vertical approach over a keyframe, the transport posture and its variants (backing off, turning on
the spot, folding, driving round the fixtures along a detour), and OMPL's base-only drive round an
obstacle, the last resort. ``SequenceGeometry`` asks for them before the reachability graph (a
transport) and after it (the drive round).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator

import numpy as np

from rlgp_exec.planning.detour import Footprint, detour, rect_distance
from rlgp_exec.planning.drawers import DrawerView
from rlgp_exec.planning.margins import FEAS_TOL
from rlgp_exec.reach import WorldChecker
from rlgp_exec.reach.graph import ReachabilityGraph
from rlgp_exec.reach.ik import base_circles
from rlgp_exec.reach.ompl_plan import drive_base, drive_postures
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import PANEL

__all__ = ["APPROACH", "MIN_RISE", "Transport"]

APPROACH = 0.12  # [m] the hand approaches and leaves each keyframe vertically over this distance
MIN_RISE = APPROACH / 2  # [m] the shortest vertical approach ``Transport.above`` accepts (a tall support)
DRIVE_ROUND_TIMEOUT = 2.0  # [s] OMPL's time for a base-only path round an obstacle (the last resort)
RETREAT = 0.3  # [m] a transport variant backs the base off this far from the nearest fixture before driving
DETOUR_MARGIN = 0.03  # [m] a detour keeps the base's enclosing circle this much further off the footprints
TUCK_IN, TUCK_UP = 0.15, 0.10  # [m] a detour's tucked posture moves the hand this far in towards the base and up
DETOUR_SLACK = 0.005  # [m] backing out of the footprints' reach goes this much past it


class Transport:
    """Straight-motion chains for one scene, checked with ``checker`` (its world: drawers, objects and a
    held object as the caller has set them); ``graph`` bounds the drive round's search."""

    def __init__(
        self,
        model: RobotModel,
        scene: Scene,
        checker: WorldChecker,
        drawers: dict[str, DrawerView],
        graph: ReachabilityGraph,
    ) -> None:
        self.model, self.scene, self.checker, self.drawers, self.graph = model, scene, checker, drawers, graph
        self.tool = model.manipulator().tool_frame

    def above(self, q_k: FloatArray) -> list[FloatArray] | None:
        """Lift APPROACH straight up from q_k, else MIN_RISE (a tall shelf may leave no more room)."""
        for rise in (APPROACH, MIN_RISE):
            chain = self._rise(q_k, rise)
            if chain is not None:
                return chain
        return None

    def _rise(self, q_k: FloatArray, rise: float) -> list[FloatArray] | None:
        """Configurations lifting the hand ``rise`` [m] straight up from q_k, the base where it is: the lift
        raised when it has the travel (one vertical motion), else the arm alone (differential IK, the hand
        keeping its orientation), as waypoints 3 cm apart."""
        for lift in ("arm_lift_joint", "torso_lift_joint"):
            if lift in self.model.joint_names:
                i = self.model.index(lift)
                top = float(self.model.limits.upper[i])
                if q_k[i] + rise <= top + FEAS_TOL:  # a keyframe NLP's lift row holds to FEAS_TOL only
                    q = q_k.copy()
                    q[i] = min(q_k[i] + rise, top)
                    return None if self.checker(q) else [q]
        # differential IK on the arm: the tool rises along world z without turning (a held object keeps
        # its attitude), 1 cm per step, re-linearised at every step
        arm = np.array(self.model.group(self.model.manipulator().group))
        lo, hi = self.model.limits.lower[arm], self.model.limits.upper[arm]
        target = np.r_[0.0, 0.0, 0.01, 0.0, 0.0, 0.0]
        q, chain = q_k.copy(), []
        for step in range(round(rise / 0.01)):
            J = self.model.jacobian(q, self.tool)[:, arm]
            dq = np.linalg.lstsq(J, target, rcond=1e-6)[0]
            q = q.copy()
            q[arm] = q[arm] + dq
            if np.any(q[arm] < lo - 1e-9) or np.any(q[arm] > hi + 1e-9) or self.checker.penetrates(q):
                return None
            if step % 3 == 2:
                chain.append(q)
        return None if not chain or self.checker(chain[-1]) else chain

    def transport(self, q1: FloatArray, q2: FloatArray) -> FloatArray | None:
        """The transport posture: raise the lift to the top, move to the other end's posture, lower it;
        None if every variant is blocked. Variants, each of straight motions checked exactly (with the
        held object, if there is one), tried in order: drive and move the arm at once; back off RETREAT
        (the base straight away from the nearest fixture footprint, heading kept), drive and
        move the arm, come in to the other end the same way; move the arm first, then drive; drive
        first, then move the arm; turn the base on the spot to the other end's heading, then drive
        (or drive, then turn; or back off, turn, drive, come in); with an empty hand, fold the arm
        (the home posture), drive, unfold (the checks do not cover a held object against the robot's
        own body); when a footprint is in the way of the straight drive, drive round the fixtures
        (``_round_variants``). A verdict on a configuration or motion that variants share is computed once."""
        lifts = [n for n in ("arm_lift_joint", "torso_lift_joint") if n in self.model.joint_names]
        if not lifts:
            return None
        i = self.model.index(lifts[0])
        top = self.model.limits.upper[i] - 0.01
        a, b = q1.copy(), q2.copy()
        a[i], b[i] = max(a[i], top), max(b[i], top)
        if self.checker(a) or self.checker(b):
            return None
        arm = np.array([j for j in self.model.group(self.model.manipulator().group) if j != i], dtype=int)
        arm_first, drive_first = a.copy(), b.copy()
        arm_first[arm], drive_first[arm] = b[arm], a[arm]
        fold_a, fold_b = a.copy(), b.copy()
        fold_a[arm] = fold_b[arm] = self.model.home()[arm]
        back_a, back_b = a.copy(), b.copy()
        for q in (back_a, back_b):
            q[:2] += RETREAT * self._away(q[:2])
        # turning on the spot at one end (the base's heading the other end's), so that the drive is
        # straight: a base rotating while it drives sweeps its corners round a nearby table's
        turn_a, turn_b, turn_back_a = a.copy(), b.copy(), back_a.copy()
        turn_a[2], turn_b[2], turn_back_a[2] = b[2], a[2], b[2]
        verdicts: dict[bytes, bool] = {}  # configuration or motion -> free
        variants = [
            [a, b],
            [a, back_a, back_b, b],
            [a, arm_first, b],
            [a, drive_first, b],
            [a, turn_a, b],
            [a, turn_b, b],
            [a, back_a, turn_back_a, back_b, b],
        ]
        if self.checker.attached is None:  # folded, a held object could reach into the body (unchecked)
            variants.append([a, fold_a, fold_b, b])
        for mid in itertools.chain(variants, self._round_variants(a, b, arm, fold_a)):
            path = [q1, *mid, q2]
            if all(self._free(verdicts, q) for q in mid[1:-1]) and all(
                self._free(verdicts, u, v) for u, v in itertools.pairwise(path)
            ):
                return np.array(path)
        return None

    def _tucked(self, q: FloatArray, arm: FloatArray) -> FloatArray | None:
        """q with the hand moved by differential IK on the joints ``arm`` (indices into q) TUCK_IN [m]
        towards the base's vertical axis and TUCK_UP [m] up, without turning (a held object keeps its
        attitude): a carrying posture that keeps a held object over the robot's side of a table and
        above the objects standing on it. 1 cm steps, each joint held at its limit once it reaches it;
        None if a step penetrates, q collides at the end, or the hand gets less than half way."""
        lo, hi = self.model.limits.lower[arm], self.model.limits.upper[arm]
        start = self.model.fk(q, self.tool)[:3, 3]
        inward = np.r_[q[:2] - start[:2], 0.0]
        norm = float(np.linalg.norm(inward))
        goal = start + np.r_[0.0, 0.0, TUCK_UP] + (TUCK_IN * inward / norm if norm > 1e-9 else 0.0)
        out = q.copy()
        for _ in range(round(float(np.linalg.norm(goal - start)) / 0.01)):
            err = goal - self.model.fk(out, self.tool)[:3, 3]
            step = err * min(1.0, 0.01 / max(float(np.linalg.norm(err)), 1e-9))
            J = self.model.jacobian(out, self.tool)[:, arm]
            dq = np.linalg.lstsq(J, np.r_[step, 0.0, 0.0, 0.0], rcond=1e-6)[0]
            out = out.copy()
            out[arm] = np.clip(out[arm] + dq, lo, hi)
            if self.checker.penetrates(out):
                return None
        moved = float(np.linalg.norm(self.model.fk(out, self.tool)[:3, 3] - start))
        return None if moved < 0.5 * float(np.linalg.norm(goal - start)) or self.checker(out) else out

    def _drive_postures(self, a: FloatArray, b: FloatArray, arm: FloatArray, fold: FloatArray) -> Iterator[FloatArray]:
        """Postures (over the joints ``arm``) for a detour, made as they are asked for: a's, b's, folded
        (``fold``'s; empty hand only: the checks do not cover a held object against the body), then
        either end's with the hand tucked in and up (``_tucked``: a held object over the robot's side
        of a table, above the objects on it)."""
        yield a[arm]
        yield b[arm]
        if self.checker.attached is None:
            yield fold[arm]
        for q in (a, b):
            tucked = self._tucked(q, arm)
            if tucked is not None:
                yield tucked[arm]

    def _round_variants(self, a: FloatArray, b: FloatArray, arm: FloatArray, fold: FloatArray) -> Iterator[list]:
        """Transport variants that drive round the fixtures when a footprint blocks the straight drive
        (``detour``: the base's enclosing circle plus DETOUR_MARGIN kept off every footprint, or, next
        to an end, as far off as that end is), one posture (``_drive_postures``) after the other: the
        posture taken at a, the detour's corners driven (the heading turning from a's to b's in
        proportion to the distance driven), b's posture taken at b; else the same from and to the ends
        backed out of the footprints' reach (heading kept), the posture taken on the way out and left
        on the way in, or taken once out and left before coming in. None when no footprint is in the way."""
        rects = self.footprints(self.checker.openings)
        if not rects:
            return
        radius = max(math.hypot(cx, cy) + r for cx, cy, r in base_circles(self.model)) + DETOUR_MARGIN
        out_a, out_b = self._clear_of(a, rects, radius), self._clear_of(b, rects, radius)
        routes = []
        ends = [(a, b)] + ([(out_a, out_b)] if out_a is not None and out_b is not None else [])
        for qa, qb in ends:
            xy = detour(qa[:2], qb[:2], rects, radius)
            if xy is not None and len(xy) > 2:  # a straight drive is the variants' before these
                s = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]
                routes.append((qa, qb, xy, s / s[-1]))
        if not routes:
            return
        turn = float(self.model.limits.difference(b, a)[2])
        for posture in self._drive_postures(a, b, arm, fold):
            for qa, qb, xy, s in routes:
                drive = []
                for k, (x, y) in enumerate(xy):
                    q = a.copy()
                    q[arm] = posture
                    q[0], q[1], q[2] = x, y, a[2] + s[k] * turn
                    drive.append(q)
                chains = [[a, *drive, b]] + ([[a, qa, *drive, qb, b]] if qa is not a else [])
                for chain in chains:
                    yield [q for k, q in enumerate(chain) if k == 0 or not np.array_equal(q, chain[k - 1])]

    def _clear_of(self, q: FloatArray, rects: list[Footprint], radius: float) -> FloatArray | None:
        """q with its base backed straight out (heading kept) until its position is ``radius`` [m] off
        every footprint in ``rects`` (at most three pushes, each away from the nearest one); None if
        that fails."""
        out = q.copy()
        for _ in range(3):
            d, k = min((rect_distance(out[:2], T, size), k) for k, (T, size) in enumerate(rects))
            if d >= radius:
                return out
            T, size = rects[k]
            local = T[:2, :2].T @ (out[:2] - T[:2, 3])
            half = np.asarray(size[:2]) / 2
            nearest = np.clip(local, -half, half)
            if d < 1e-9:  # inside: out across the nearest side
                return None
            out[:2] += (T[:2, :2] @ (local - nearest)) / d * (radius - d + DETOUR_SLACK)
        return out if all(rect_distance(out[:2], T, size) >= radius for T, size in rects) else None

    def _away(self, xy: FloatArray) -> FloatArray:
        """Unit vector (2,) in the world plane from the nearest point of the nearest fixture footprint
        to ``xy`` [m] (zero if there is no fixture or xy is inside one)."""
        best, out = np.inf, np.zeros(2)
        for fx in self.scene.fixtures:
            local = fx.T[:2, :2].T @ (xy - fx.T[:2, 3])
            nearest = np.clip(local, -np.asarray(fx.size[:2]) / 2, np.asarray(fx.size[:2]) / 2)
            d = float(np.linalg.norm(local - nearest))
            if d < best:
                best, out = d, (fx.T[:2, :2] @ (local - nearest)) / d if d > 1e-9 else np.zeros(2)
        return out

    def footprints(self, openings: dict[str, float]) -> list[Footprint]:
        """The footprints the base keeps off: the fixtures', and each drawer out at ``openings`` [m]."""
        rects: list[Footprint] = [(fx.T, np.asarray(fx.size)) for fx in self.scene.fixtures]
        rects += [(v.T_world_drawer(openings[c]), np.asarray(v.geometry.inner_box.size) + 2 * PANEL)
                  for c, v in self.drawers.items() if openings.get(c, 0.0) > 0.0]
        return rects

    def drive_round(self, q1: FloatArray, q2: FloatArray) -> FloatArray | None:
        """The last resort when the graph finds no path (e.g. round a cabinet to its far side): the
        arm (and a torso outside it, raised to the top) takes a posture at q1's base, OMPL plans the
        base alone (3 DoF, the posture rigid: a held object keeps its place relative to the robot) to
        q2's base, and the arm takes q2's posture; each motion checked exactly. Postures tried: q2's
        own; folded (the home posture, empty hand only: the checks do not cover a held object against
        the robot's body); q1's with the lift up. None if all fail."""
        rigid, postures = drive_postures(self.model, q1, q2, empty_hand=self.checker.attached is None)
        X = self.graph.X[self.graph.alive]
        lo_xy, hi_xy = X[:, :2].min(axis=0) - 1.0, X[:, :2].max(axis=0) + 1.0
        verdicts: dict[bytes, bool] = {}

        def free(q: FloatArray, q_to: FloatArray | None = None) -> bool:
            return self._free(verdicts, q, q_to)

        return drive_base(
            self.checker,
            q1,
            q2,
            rigid,
            postures,
            lo_xy,
            hi_xy,
            DRIVE_ROUND_TIMEOUT,
            free,
        )

    def _free(self, verdicts: dict[bytes, bool], q: FloatArray, q_to: FloatArray | None = None) -> bool:
        """q is collision-free (or, with ``q_to``, the straight motion q -> q_to is), remembered in ``verdicts``."""
        key = q.tobytes() + (b"" if q_to is None else q_to.tobytes())
        if key not in verdicts:
            verdicts[key] = not (self.checker(q) if q_to is None else self.checker.edge_collides(q, q_to))
        return verdicts[key]
