"""Geometry for one candidate action sequence: keyframes (level 2), guided paths between them from the
reachability graph (getWaypoints), and validation by replay.

Each action is approached and left vertically: the hand goes to ``APPROACH`` above its keyframe
(position IK warm-started from the keyframe) and then straight down, and back up afterwards, so that a
held object is carried above the support surfaces. Between those approach configurations the guided
paths (the graph's collision-checked waypoints, getWaypoints, or a transport / drive-round chain) warm
start level 3 (``nlp.path``): one NLP over all of them, T waypoints each, the approach configurations
fixed (level 2's keyframes are the switches). The graph's waypoints are greedily shortcut first
(~0.2 s a plan on pick_place_pr2, while level 3 takes ~1-2 s: it does not replace the shortcut, it
starts from it and falls back to it). The replay decides; a level-3 segment the replay finds
colliding is put back to its guided path and the plan replayed again (Algorithm 1's replanning when
level 3 fails). ``level3=False`` keeps the guided paths only.
"""

from __future__ import annotations

import itertools
import logging
import math
import time
from collections.abc import Iterator
from dataclasses import dataclass, replace

import numpy as np

from rlgp_exec.planning.budget import cpu_clock
from rlgp_exec.planning.detour import Footprint, detour, rect_distance
from rlgp_exec.planning.drawers import drawer_views
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.nlp.hand import (
    arm_link_spheres,
    body_obstacles,
    finger_spheres,
    inner_obstacles,
    mesh_finger_spheres,
    other_arm_obstacles,
)
from rlgp_exec.planning.nlp.keyframes import DRAWER_ACTIONS, Action, solve_keyframes
from rlgp_exec.planning.nlp.path import T_DEFAULT, Segment, optimize_paths
from rlgp_exec.planning.plan import Level3Stats, Plan
from rlgp_exec.planning.validate import Phase, validate_with_fallbacks
from rlgp_exec.reach import ReachabilityPlanner, ReachIK, RGParams, WorldChecker, load_or_build, nominal_q
from rlgp_exec.reach.ik import base_circles
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import PANEL, Box, fixture_boxes, object_box

__all__ = ["APPROACH", "SequenceGeometry"]

APPROACH = 0.12  # [m] the hand approaches and leaves each keyframe vertically over this distance
DRIVE_ROUND_TIMEOUT = 2.0  # [s] OMPL's time for a base-only path round an obstacle (the last resort)
RETREAT = 0.3  # [m] a transport variant backs the base off this far from the nearest fixture before driving
DETOUR_MARGIN = 0.03  # [m] a detour keeps the base's enclosing circle this much further off the footprints
TUCK_IN, TUCK_UP = 0.15, 0.10  # [m] a detour's tucked posture moves the hand this far in towards the base and up
DETOUR_SLACK = 0.005  # [m] backing out of the footprints' reach goes this much past it

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class _Guide:
    """A guided path of a candidate plan: where it sits (the first rows of phase ``phase``) and the world
    it was planned in (for level 3's segment)."""

    phase: int
    path: FloatArray  # (m, nq) the guide's waypoints (the graph's shortcut, or a transport / drive chain)
    openings: dict[str, float]
    objects: tuple[Box, ...]  # the standing objects
    held: str | None
    T_tool_obj: FloatArray | None


class SequenceGeometry:
    """Everything geometric the R-LGP loop asks of a scene: heuristic costs and waypoints from the
    reachability graph, keyframe NLPs, and validated plans for candidate sequences."""

    def __init__(
        self,
        scene: Scene,
        params: RGParams | None = None,
        seed: int = 0,
        memory: PlannerMemory | None = None,
        level3: bool = True,
        T: int = T_DEFAULT,
    ) -> None:
        """``memory``: where the reachability graph comes from and stays (with what queries teach it)
        for the next call; without one, the cached graph is loaded for this call only. ``level3``:
        optimise the guided paths (``nlp.path``, ``T`` waypoints per segment)."""
        self.scene, self.seed = scene, seed
        self.model = load_robot(scene.robot.name)
        self.q0 = nominal_q(self.model, scene)
        if memory is not None:
            self.graph, self.graph_stats = memory.graph(scene, params or RGParams())
        else:
            self.graph, self.graph_stats = load_or_build(scene, params=params or RGParams())
        self.checker = WorldChecker(scene, self.model.manipulator().group)
        self.ik = ReachIK(self.model, scene, self.q0)
        self.rg = ReachabilityPlanner(self.graph, self.ik, self.checker, rng_seed=seed)
        self.drawers = drawer_views(scene)
        self.hand = finger_spheres(self.checker.robot, self.model, self.q0)
        self.mesh_hand = mesh_finger_spheres(self.checker.robot, self.model, self.q0)  # keyframes only
        self.self_spheres = arm_link_spheres(self.model)
        self.body = body_obstacles(self.checker.robot, self.model, self.q0)
        # level 3's self-clearance: the body and the other arms where q0 has them
        self.l3_body = self.body + other_arm_obstacles(self.checker.robot, self.model, self.q0)
        # the keyframes': the chest and the other arms' shoulders, kept off the upper arm (an arm turned inwards)
        self.inner = inner_obstacles(self.checker.robot, self.model, self.q0)
        self.tool = self.model.manipulator().tool_frame
        self.n_nlp = 0
        self.level3, self.T = level3, T
        self.l3 = Level3Stats()  # totals over this object's candidates
        self._nlp_cache: dict = {}  # the keyframe NLP of the sequence under way (its tilts share it)

    def close(self) -> None:
        self.checker.close()

    @property
    def hand_start(self) -> FloatArray:
        return self.model.fk(self.q0, self.tool)[:3, 3]

    def heuristic_cost(self, x1: FloatArray, x2: FloatArray) -> float:
        """heuristicCost: the reachability graph's path cost between two hand positions (inf if none),
        estimated on the graph as it stands (no IK or collision checks: the symbolic search asks often)."""
        return self.rg.estimate(x1, x2)

    def _above(self, q_k: FloatArray) -> list[FloatArray] | None:
        """Lift APPROACH straight up from q_k, else half of it (a tall shelf may leave no more room)."""
        for rise in (APPROACH, APPROACH / 2):
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
                if q_k[i] + rise <= self.model.limits.upper[i]:
                    q = q_k.copy()
                    q[i] += rise
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

    def _transport(self, q1: FloatArray, q2: FloatArray) -> FloatArray | None:
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

    def _footprints(self, openings: dict[str, float]) -> list[Footprint]:
        """The footprints the base keeps off: the fixtures', and each drawer out at ``openings`` [m]."""
        rects: list[Footprint] = [(fx.T, np.asarray(fx.size)) for fx in self.scene.fixtures]
        rects += [(v.T_world_drawer(openings[c]), np.asarray(v.geometry.inner_box.size) + 2 * PANEL)
                  for c, v in self.drawers.items() if openings.get(c, 0.0) > 0.0]
        return rects

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
        rects = self._footprints(self.checker.openings)
        if not rects:
            return
        radius = max(math.hypot(cx, cy) + r for cx, cy, r in base_circles(self.model)) + DETOUR_MARGIN
        out_a, out_b = self._clear_of(a, rects, radius), self._clear_of(b, rects, radius)
        routes = []
        for qa, qb in ((a, b), (out_a, out_b)):
            xy = None if qa is None or qb is None else detour(qa[:2], qb[:2], rects, radius)
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

    def _free(self, verdicts: dict[bytes, bool], q: FloatArray, q_to: FloatArray | None = None) -> bool:
        """q is collision-free (or, with ``q_to``, the straight motion q -> q_to is), remembered in ``verdicts``."""
        key = q.tobytes() + (b"" if q_to is None else q_to.tobytes())
        if key not in verdicts:
            verdicts[key] = not (self.checker(q) if q_to is None else self.checker.edge_collides(q, q_to))
        return verdicts[key]

    def plan_actions(
        self,
        actions: list[Action],
        planner: str = "rlgp",
        nodes_expanded: int = 0,
        t_start: float | None = None,
        deadline: float | None = None,
    ) -> Plan:
        """Keyframes, guided paths and replay for one action sequence. Vertical grasps first; hands
        leaning up to 0.6 rad (which reach further across a table) when the vertical attempt fails.
        ``deadline`` (``budget.cpu_clock()`` [s]): no new keyframe start or tilt after it."""
        t0 = time.perf_counter() if t_start is None else t_start
        reasons = []
        for tilt in (0.0, 0.6):
            if reasons and deadline is not None and cpu_clock() > deadline:
                break
            result = self._attempt(actions, planner, nodes_expanded, t0, tilt, deadline)
            if result.success:
                return result
            reasons.append(f"[tilt <= {tilt} rad] {result.reason}")
        return replace(result, reason=" / ".join(reasons))

    def _graph_seeds(self, x: FloatArray) -> list[FloatArray]:
        """Keyframe seeds for a hand target x: the graph's nearest nodes (collision-free, reaching near x)."""
        return self.rg.node_seeds(x, 8)

    def _along_axis(self, q: FloatArray, cabinet: str, distance: float) -> FloatArray:
        """q with the base moved ``distance`` [m] along the cabinet's opening axis (out of it if > 0)."""
        out = q.copy()
        out[:2] += distance * self.drawers[cabinet].axis_world[:2]
        return out

    def _in_collision(
        self, q: FloatArray, openings: dict[str, float], action: Action, objects: dict[str, FloatArray] | None = None
    ) -> bool:
        """The keyframe check, with the drawers at ``openings`` and the ``objects`` (name -> T_world_obj)
        where they stand: a pick, place or drop keeps CLEARANCE from them and the fixtures; a drawer
        action only must not penetrate anything (its fingers may touch the knob)."""
        self.checker.set_drawers(openings)
        self.checker.set_objects([replace(object_box(self.scene.object(m)), T=T) for m, T in (objects or {}).items()])
        self.checker.touch_knob(action.obj if action.name in DRAWER_ACTIONS else None)
        try:
            if action.name in DRAWER_ACTIONS:  # the fingers round the knob come close to the drawer front
                return self.checker.penetrates(q)
            # a grasp or release keeps the graph's clearance: closing fingers and a real hand's tolerances
            # must not start it against a wall (the approach from above starts there too)
            return self.checker(q)
        finally:
            self.checker.touch_knob(None)
            self.checker.set_objects([])

    def _guided(self, q_prev: FloatArray, q_pre: FloatArray, held: str | None, T_tool_obj: FloatArray | None):
        """The guided path q_prev -> q_pre (transport posture, else the graph), or the failure reason."""
        x1, x2 = self.model.fk(q_prev, self.tool)[:3, 3], self.model.fk(q_pre, self.tool)[:3, 3]
        if held is None:
            self.rg.carrying(None)
        else:  # the graph's paths must clear the held object too
            self.rg.carrying(np.asarray(self.scene.object(held).size), T_tool_obj)
        try:
            transport = self._transport(q_prev, q_pre)
            if transport is not None:
                return transport
            res = self.rg.query(x1, x2, q1=q_prev, q2=q_pre)
            if not res.ok:
                around = self._drive_round(q_prev, q_pre)
                return around if around is not None else f"{res.status.value}: {res.reason}"
            return self._shortcut(res.path)
        finally:
            self.rg.carrying(None)

    def _segment(self, g: _Guide) -> Segment:
        """Level 3's view of a guide: the world boxes (fixtures, drawers at their openings, the standing
        objects), the footprints the base avoids (fixtures, open drawers) and the held object."""
        drawer_bx = [b for c, v in self.drawers.items() for b in v.boxes(g.openings[c])]
        rects = self._footprints(g.openings)
        boxes = [b for fx in self.scene.fixtures for b in fixture_boxes(fx)] + drawer_bx + list(g.objects)
        held = None if g.held is None else (np.asarray(self.scene.object(g.held).size), g.T_tool_obj)
        return Segment(g.path, tuple(boxes), tuple(rects), held)

    def _optimise(
        self, phases: list[Phase], guides: list[_Guide]
    ) -> tuple[list[Phase], dict[int, _Guide], tuple[float, float] | None]:
        """Level 3 on every guide: the phases with the optimised paths in place of the guides' (a segment
        level 3 failed on keeps its guide), the guides whose phases now hold a level-3 path (by phase),
        and (their acceleration cost, their warm start's), or None when level 3 failed on every segment
        (the phases unchanged)."""
        segs = [self._segment(g) for g in guides]
        res = optimize_paths(self.model, segs, self.T, hand=self.hand, self_spheres=self.self_spheres,
                             body=self.l3_body)
        self.l3 = replace(
            self.l3, attempts=self.l3.attempts + 1, solved=self.l3.solved + res.ok,
            time_s=self.l3.time_s + res.build_s + res.solve_s, jac_nnz=res.jac_nnz, n_var=res.n_var,
        )
        log.info("level 3: %s, acceleration cost %.3g (warm start %.3g), %d iterations, %.2f s + %.2f s, "
                 "%d rows relaxed", res.reason, res.acc_cost, res.warm_acc_cost, res.iterations, res.build_s,
                 res.solve_s, res.relaxed)
        # Algorithm 1's fallback: a segment level 3 failed on keeps its guided path
        kept = [(g, path, c, c0) for g, path, c, c0, ok in
                zip(guides, res.paths, res.acc_costs, res.warm_acc_costs, res.optimised, strict=True) if ok]
        if not kept:
            return phases, {}, None
        out = list(phases)
        for g, path, _, _ in kept:
            ph = out[g.phase]
            out[g.phase] = replace(ph, path=np.vstack([path, ph.path[len(g.path):]]))
        return out, {g.phase: g for g, *_ in kept}, (sum(k[2] for k in kept), sum(k[3] for k in kept))

    def _replay(self, phases: list[Phase], optimised: dict[int, _Guide]):
        """validate_plan; a collision in a level-3 phase puts that phase back to its guide (shortcut) and
        replays again (``validate_with_fallbacks``). Returns (validation, phases, the level-3 phases
        still in them)."""
        # the first T rows of a level-3 phase are level 3's: its guide instead
        fallbacks = {k: replace(phases[k], path=np.vstack([g.path, phases[k].path[self.T:]]))
                     for k, g in optimised.items()}
        validation, out, kept = validate_with_fallbacks(self.scene, phases, fallbacks)
        self.l3 = replace(self.l3, fallbacks=self.l3.fallbacks + len(optimised) - len(kept))
        return validation, out, {k: g for k, g in optimised.items() if k in kept}

    def _drive_round(self, q1: FloatArray, q2: FloatArray) -> FloatArray | None:
        """The last resort when the graph finds no path (e.g. round a cabinet to its far side): the
        arm (and a torso outside it, raised to the top) takes a posture at q1's base, OMPL plans the
        base alone (3 DoF, the posture rigid: a held object keeps its place relative to the robot) to
        q2's base, and the arm takes q2's posture; each motion checked exactly. Postures tried: q2's
        own; folded (the home posture, empty hand only: the checks do not cover a held object against
        the robot's body); q1's with the lift up. None if all fail."""
        from rlgp_exec.reach.ompl_plan import drive_base, drive_postures

        rigid, postures = drive_postures(self.model, q1, q2, empty_hand=self.checker.attached is None)
        X = self.graph.X[self.graph.alive]
        lo_xy, hi_xy = X[:, :2].min(axis=0) - 1.0, X[:, :2].max(axis=0) + 1.0
        verdicts: dict[bytes, bool] = {}
        return drive_base(
            self.checker,
            q1,
            q2,
            rigid,
            postures,
            lo_xy,
            hi_xy,
            DRIVE_ROUND_TIMEOUT,
            lambda q, q_to=None: self._free(verdicts, q, q_to),
        )

    def _shortcut(self, path: FloatArray, max_checks: int = 24) -> FloatArray:
        """Greedy shortcuts of a guided path: from each kept waypoint, the farthest later one reachable
        by a straight, checked motion (with the held object, if any); at most ``max_checks`` checks."""
        keep, i, checks = [0], 0, 0
        while i < len(path) - 1:
            nxt = i + 1
            for j in range(len(path) - 1, i + 1, -1):
                if checks >= max_checks:
                    break
                checks += 1
                if not self.checker.edge_collides(path[i], path[j]):
                    nxt = j
                    break
            keep.append(nxt)
            i = nxt
        return path[keep]

    def _attempt(
        self, actions: list[Action], planner: str, nodes_expanded: int, t0: float, tilt: float, deadline: float | None
    ) -> Plan:
        names = tuple(str(a) for a in actions)
        self.n_nlp += 1
        kf = solve_keyframes(
            self.model,
            self.scene,
            self.q0,
            actions,
            seed=self.seed,
            in_collision=self._in_collision,
            max_tilt=tilt,
            ik=self.ik,
            hand=self.hand,
            self_spheres=self.self_spheres,
            body=self.body,
            lift_room=APPROACH,
            seeds=self._graph_seeds,
            deadline=deadline,
            cache=self._nlp_cache,
            mesh_hand=self.mesh_hand,
            inner=self.inner,
        )
        empty = np.zeros((0, self.model.nq))

        def fail(reason: str, phases: tuple[Phase, ...] = ()) -> Plan:
            self.rg.drawers({c: 0.0 for c in self.drawers})
            self.checker.set_objects([])
            return Plan(
                False,
                planner,
                names,
                kf.keyframes if kf.ok else empty,
                phases,
                time.perf_counter() - t0,
                self.n_nlp,
                nodes_expanded,
                None,
                reason,
                level3=self.l3 if self.level3 else None,
            )

        if not kf.ok:
            return fail(f"keyframes (tilt <= {tilt} rad): {kf.reason}")
        phases: list[Phase] = []
        guides: list[_Guide] = []
        start = self.scene.start
        q_prev, held = self.q0, start.held
        T_tool_obj = None if held is None else start.T_tool_obj
        openings = {c: start.opening(c) for c in self.drawers}
        for k, (a, q_k) in enumerate(zip(actions, kf.keyframes, strict=True)):
            if a.name in ("open_drawer", "close_drawer"):  # the hand on the knob drives the drawer
                phases.append(Phase(np.array([q_prev, q_k]), None, knob=a.obj, drives_drawer=True))
                openings = dict(kf.openings[k])
                q_leave = self._along_axis(q_k, a.obj, APPROACH)  # let go, back off along the axis
                phases.append(Phase(np.array([q_k, q_leave]), None, knob=a.obj))
                q_prev = q_leave
                continue
            self.rg.drawers(openings)
            before = kf.object_poses[k - 1] if k else {o.name: o.T for o in self.scene.objects}  # held: skipped
            self.checker.set_objects(  # the objects where they stand are obstacles for the guided path
                [replace(object_box(o), T=before[o.name]) for o in self.scene.objects if o.name != held]
            )
            if a.name == "take_knob":  # approached along the drawer's axis
                q_pre = self._along_axis(q_k, a.obj, APPROACH)
                if self.checker(q_pre):
                    return fail(f"no approach configuration {APPROACH:.2f} m out from {a}", tuple(phases))
                up: list[FloatArray] = []
            else:
                up_or_none = self._above(q_k)
                if up_or_none is None:
                    return fail(f"no approach configuration {APPROACH:.2f} m above {a}", tuple(phases))
                up = up_or_none
                q_pre = up[-1]
            guided = self._guided(q_prev, q_pre, held, T_tool_obj)
            if isinstance(guided, str):
                return fail(f"no guided path to {a}: {guided}", tuple(phases))
            standing = tuple(replace(object_box(o), T=before[o.name]) for o in self.scene.objects if o.name != held)
            guides.append(_Guide(len(phases), guided, dict(openings), standing, held, T_tool_obj))
            down = np.vstack([guided, np.array(up[-2::-1]).reshape(-1, self.model.nq), q_k[None]])
            if a.name == "take_knob":
                phases.append(Phase(down, None, knob=a.obj))
                q_prev = q_k
                continue
            if a.name == "pick":
                phases.append(Phase(down, None, grasp=a.obj))
                held = a.obj
                T_tool_obj = np.linalg.inv(self.model.fk(q_k, self.tool)) @ kf.object_poses[k][a.obj]
            else:
                phases.append(Phase(down, held, release=a.obj, fall=a.name == "drop"))
                held, T_tool_obj = None, None
            phases.append(Phase(np.vstack([q_k[None], np.array(up)]), held))  # leave vertically
            q_prev = q_pre
        self.rg.drawers({c: 0.0 for c in self.drawers})
        self.checker.set_objects([])
        optimised: dict[int, _Guide] = {}
        costs = None
        if self.level3 and guides:
            phases, optimised, costs = self._optimise(phases, guides)
        validation, phases, optimised = self._replay(phases, optimised)
        if validation.ok and optimised:
            self.l3 = replace(self.l3, used=self.l3.used + 1)
        if validation.ok:  # the returned plan's level-3 costs (None when a segment fell back)
            whole = costs is not None and len(optimised) == len(guides)
            self.l3 = replace(self.l3, acc_cost=costs[0] if whole else None,
                              warm_acc_cost=costs[1] if whole else None)
        reason = "ok" if validation.ok else "; ".join([*validation.collisions[:3], *validation.unmet])
        return Plan(
            validation.ok,
            planner,
            names,
            kf.keyframes,
            tuple(phases),
            time.perf_counter() - t0,
            self.n_nlp,
            nodes_expanded,
            validation,
            reason,
            level3=self.l3 if self.level3 else None,
        )
