"""Geometry for one candidate action sequence: keyframes (level 2), guided paths between them from the
reachability graph (getWaypoints), and validation by replay.

Each action is approached and left vertically: the hand goes to ``APPROACH`` above its keyframe
(position IK warm-started from the keyframe) and then straight down, and back up afterwards, so that a
held object is carried above the support surfaces. Between those approach configurations the guided
paths (the graph's collision-checked waypoints, getWaypoints, or a transport / drive-round chain from
``planning.transport``) warm start level 3 (``nlp.path``): one NLP per guided path, T waypoints each,
the approach configurations fixed (level 2's keyframes are the switches). The graph's waypoints are
greedily shortcut first (cheap against level 3: it does not replace the shortcut, it starts from it
and falls back to it). The replay decides; a level-3 segment the replay finds
colliding is put back to its guided path and the plan replayed again (Algorithm 1's replanning when
level 3 fails). ``level3=False`` keeps the guided paths only.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace
from typing import NamedTuple

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning import budget
from rlgp_exec.planning.actions import DRAWER_ACTIONS, Kind, named_arm
from rlgp_exec.planning.drawers import drawer_views
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.hand import (
    arm_link_spheres,
    body_obstacles,
    finger_spheres,
    inner_obstacles,
    mesh_finger_spheres,
    mesh_finger_tips,
    other_arm_obstacles,
)
from rlgp_exec.planning.nlp.keyframe_chunks import JOINT_ACTIONS, ChunkedKeyframes
from rlgp_exec.planning.nlp.keyframes import KeyframeResult, solve_keyframes
from rlgp_exec.planning.nlp.path import T_DEFAULT, Segment, optimize_paths
from rlgp_exec.planning.nlp.pick_fingers import palm_box_spheres
from rlgp_exec.planning.plan import Level3Stats, Plan
from rlgp_exec.planning.transport import APPROACH, MIN_RISE, Transport
from rlgp_exec.planning.validate import Phase, Validation, validate_with_fallbacks
from rlgp_exec.reach import ReachabilityPlanner, ReachIK, RGParams, WorldChecker, load_or_build, nominal_q
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Box, fixture_boxes, object_box

__all__ = ["APPROACH", "STAGES", "SequenceGeometry"]


log = logging.getLogger(__name__)
# where a plan's time goes (``Plan.stages``): this object's set-up (robot, graph, PyBullet world, IK), the
# keyframe NLPs (level 2), the guided paths (approaches, graph queries, transports), level 3, the replay
STAGES = ("setup", "keyframes", "guided", "level3", "replay")
_STAGE_NAMES = {"guided": "guided paths", "level3": "level 3"}  # in a budget's reason


#: [rad] the grasps' largest lean from vertical, tried in turn (a lean reaches further across a table)
TILTS = (0.0, 0.6)


class _NoLayout(NamedTuple):
    """Why a candidate's phases could not be laid out, and those laid out before."""

    reason: str
    phases: tuple[Phase, ...]


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
        t0 = time.perf_counter()
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
        self.moves = Transport(self.model, scene, self.checker, self.drawers, self.graph)
        self.hand = finger_spheres(self.checker.robot, self.model, self.q0)
        self.mesh_hand = mesh_finger_spheres(self.checker.robot, self.model, self.q0)  # keyframes only
        self.palm_hand = palm_box_spheres(self.checker.robot, self.model, self.q0)  # picks' keyframes only
        self.tip_points = mesh_finger_tips(self.checker.robot, self.model, self.q0)  # by a flat object's support
        self.self_spheres = arm_link_spheres(self.model)
        self.body = body_obstacles(self.checker.robot, self.model, self.q0)
        # level 3's self-clearance: the body and the other arms where q0 has them
        self.l3_body = self.body + other_arm_obstacles(self.checker.robot, self.model, self.q0)
        # the keyframes': the chest and the other arms' shoulders, kept off the upper arm (an arm turned inwards)
        self.inner = inner_obstacles(self.checker.robot, self.model, self.q0)
        self.tool = self.model.manipulator().tool_frame
        #: the arm as ``Plan.actions`` names it (None: the robot has one)
        self.arm_named = named_arm([m.name for m in self.model.config.manipulators], self.model.manipulator().name)
        self.n_nlp = 0
        self.level3, self.T = level3, T
        self.l3 = Level3Stats()  # totals over this object's candidates
        self._nlp_cache: dict = {}  # the keyframe NLP of the sequence under way (its tilts share it)
        self._chunked = ChunkedKeyframes()  # a long sequence's, chunk by chunk
        self.stages = dict.fromkeys(STAGES, 0.0)  # [s] summed over this object's calls
        self.stages["setup"] = time.perf_counter() - t0

    @contextmanager
    def _stage(self, name: str) -> Iterator[None]:
        t0 = time.perf_counter()
        b = budget.active()
        try:
            if b is None:
                yield
            else:
                with b.at(_STAGE_NAMES.get(name, name)):
                    yield
        finally:
            self.stages[name] += time.perf_counter() - t0

    def close(self) -> None:
        self.checker.close()

    def reset(self) -> None:
        """The world of the graph's queries back to the scene's start (after a stage cut short)."""
        self.rg.carrying(None)
        self.rg.drawers({c: 0.0 for c in self.drawers})
        self.checker.set_objects([])
        self.checker.touch_knob(None)

    @property
    def hand_start(self) -> FloatArray:
        return self.model.fk(self.q0, self.tool)[:3, 3]

    def heuristic_cost(self, x1: FloatArray, x2: FloatArray) -> float:
        """heuristicCost: the reachability graph's path cost between two hand positions (inf if none),
        estimated on the graph as it stands (no IK or collision checks: the symbolic search asks often)."""
        return self.rg.estimate(x1, x2)

    def plan_actions(
        self,
        actions: list[Action],
        planner: str = "rlgp",
        nodes_expanded: int = 0,
        t_start: float | None = None,
    ) -> Plan:
        """Keyframes, guided paths and replay for one action sequence. Vertical grasps first; hands
        leaning up to 0.6 rad (which reach further across a table) when the vertical attempt fails.
        The active budget (``planning.budget``) is checked inside every stage: ``BudgetError`` once spent."""
        t0 = time.perf_counter() if t_start is None else t_start
        reasons: list[str] = []
        doomed = []
        for tilt in TILTS:
            result = self._attempt(actions, planner, nodes_expanded, t0, tilt)
            if result.success:
                return result
            reasons.append(f"[tilt <= {tilt} rad] {result.reason}")
            doomed.append(result.doomed)
        # a prefix fails whatever follows only if it does at every tilt
        return replace(result, reason=" / ".join(reasons), doomed=max(doomed) if all(doomed) else 0)

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
            transport = self.moves.transport(q_prev, q_pre)
            if transport is not None:
                return transport
            res = self.rg.query(x1, x2, q1=q_prev, q2=q_pre)
            if not res.ok:
                around = self.moves.drive_round(q_prev, q_pre)
                return around if around is not None else f"{res.status.value}: {res.reason}"
            return self._shortcut(res.path)
        finally:
            self.rg.carrying(None)

    def _segment(self, g: _Guide) -> Segment:
        """Level 3's view of a guide: the world boxes (fixtures, drawers at their openings, the standing
        objects), the footprints the base avoids (fixtures, open drawers) and the held object."""
        drawer_bx = [b for c, v in self.drawers.items() for b in v.boxes(g.openings[c])]
        rects = self.moves.footprints(g.openings)
        boxes = [b for fx in self.scene.fixtures for b in fixture_boxes(fx)] + drawer_bx + list(g.objects)
        held = None
        if g.held is not None:
            if g.T_tool_obj is None:
                raise RlgpError(f"guided path of phase {g.phase}: {g.held} held without its grasp T_tool_obj")
            held = (np.asarray(self.scene.object(g.held).size, float), g.T_tool_obj)
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
            time_s=self.l3.time_s + res.wall_s, jac_nnz=res.jac_nnz, n_var=res.n_var,
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
        """validate_plan; a collision in a level-3 phase puts that phase back to its guide (shortcut), which
        the replay then follows from where the phase started (``validate_with_fallbacks``). Returns
        (validation, phases, the level-3 phases still in them)."""
        # the first T rows of a level-3 phase are level 3's: its guide instead
        fallbacks = {k: replace(phases[k], path=np.vstack([g.path, phases[k].path[self.T:]]))
                     for k, g in optimised.items()}
        validation, out, kept = validate_with_fallbacks(self.scene, phases, fallbacks)
        self.l3 = replace(self.l3, fallbacks=self.l3.fallbacks + len(optimised) - len(kept))
        return validation, out, {k: g for k, g in optimised.items() if k in kept}

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
        self, actions: list[Action], planner: str, nodes_expanded: int, t0: float, tilt: float
    ) -> Plan:
        names = tuple(a.text(self.arm_named) for a in actions)
        self.n_nlp += 1
        with self._stage("keyframes"):
            kf = self._keyframes(actions, tilt)

        def result(phases: tuple[Phase, ...], validation: Validation | None, reason: str) -> Plan:
            return Plan(
                validation is not None and validation.ok,
                planner,
                names,
                kf.keyframes if kf.ok else np.zeros((0, self.model.nq)),
                phases,
                time.perf_counter() - t0,
                self.n_nlp,
                nodes_expanded,
                validation,
                reason,
                level3=self.l3 if self.level3 else None,
                stages=dict(self.stages),
            )

        def fail(reason: str, phases: tuple[Phase, ...] = ()) -> Plan:
            self.rg.drawers({c: 0.0 for c in self.drawers})
            self.checker.set_objects([])
            return result(phases, None, reason)

        if not kf.ok:
            return replace(fail(f"keyframes (tilt <= {tilt} rad): {kf.reason}"), doomed=kf.doomed)
        with self._stage("guided"):
            laid = self._lay_out(actions, kf)
        if isinstance(laid, _NoLayout):
            return fail(*laid)
        phases, guides = laid
        optimised: dict[int, _Guide] = {}
        costs = None
        if self.level3 and guides:
            with self._stage("level3"):
                phases, optimised, costs = self._optimise(phases, guides)
        with self._stage("replay"):
            validation, phases, optimised = self._replay(phases, optimised)
        if validation.ok and optimised:
            self.l3 = replace(self.l3, used=self.l3.used + 1)
        if validation.ok:  # the returned plan's level-3 costs (None when a segment fell back)
            whole = costs if len(optimised) == len(guides) else None
            self.l3 = replace(self.l3, acc_cost=whole[0] if whole else None,
                              warm_acc_cost=whole[1] if whole else None)
        reason = "ok" if validation.ok else "; ".join([*validation.collisions[:3], *validation.unmet])
        return result(tuple(phases), validation, reason)

    def _keyframes(self, actions: list[Action], tilt: float) -> KeyframeResult:
        """Level 2 for ``actions`` (chunk by chunk when long: ``nlp.keyframe_chunks``)."""
        if len(actions) <= JOINT_ACTIONS:
            return self._solve_keyframes(self.scene, self.q0, actions, tilt, self._nlp_cache)

        tilts = [t for t in TILTS if t >= tilt]
        return self._chunked(self._solve_keyframes, self.scene, self.q0, actions, tilts)

    def _solve_keyframes(
        self, scene: Scene, q_start: FloatArray, actions: list[Action], tilt: float, cache: dict
    ) -> KeyframeResult:
        return solve_keyframes(
            self.model,
            scene,
            q_start,
            actions,
            seed=self.seed,
            in_collision=self._in_collision,
            max_tilt=tilt,
            ik=self.ik,
            hand=self.hand,
            self_spheres=self.self_spheres,
            body=self.body,
            lift_room=MIN_RISE,  # what the vertical leave needs at least (``Transport.above``): more would bar
            # the places only a full lift reaches (a vertical hand on a 0.7 m desk: a cylinder cannot lean)
            seeds=self._graph_seeds,
            cache=cache,
            mesh_hand=self.mesh_hand,
            palm_hand=self.palm_hand,
            inner=self.inner,
            tip_points=self.tip_points,
        )

    def _lay_out(self, actions: list[Action], kf: KeyframeResult) -> tuple[list[Phase], list[_Guide]] | _NoLayout:
        """The phases through the keyframes (vertical approaches and leaves, the drawer motions) and the
        guided paths between them, or why there are none (with the phases laid out so far)."""
        phases: list[Phase] = []
        guides: list[_Guide] = []
        start = self.scene.start
        q_prev, held = self.q0, start.held
        T_tool_obj = None if held is None else start.T_tool_obj
        openings = {c: start.opening(c) for c in self.drawers}
        if held is not None:  # a replan with an object in the hand (a violation right after its grasp): leave
            # vertically first, as after a pick; resting on its support, the held object has no guided path
            # out of there ("start_unreachable"). Where there is no room above, the guided path starts here
            self.checker.set_objects([object_box(o) for o in self.scene.objects if o.name != held])
            up0 = self.moves.above(self.q0)
            if up0 is not None:
                phases.append(Phase(np.vstack([self.q0[None], np.array(up0)]), held))
                q_prev = up0[-1]
        for k, (a, q_k) in enumerate(zip(actions, kf.keyframes, strict=True)):
            if a.name in (Kind.OPEN_DRAWER, Kind.CLOSE_DRAWER):  # the hand on the knob drives the drawer
                phases.append(Phase(np.array([q_prev, q_k]), None, knob=a.obj, drives_drawer=True, action=k))
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
            if a.name == Kind.TAKE_KNOB:  # approached along the drawer's axis
                q_pre = self._along_axis(q_k, a.obj, APPROACH)
                if self.checker(q_pre):
                    return _NoLayout(f"no approach configuration {APPROACH:.2f} m out from {a}", tuple(phases))
                up: list[FloatArray] = []
            else:
                up_or_none = self.moves.above(q_k)
                if up_or_none is None:
                    return _NoLayout(f"no approach configuration {APPROACH:.2f} m above {a}", tuple(phases))
                up = up_or_none
                q_pre = up[-1]
            guided = self._guided(q_prev, q_pre, held, T_tool_obj)
            if isinstance(guided, str):
                return _NoLayout(f"no guided path to {a}: {guided}", tuple(phases))
            standing = tuple(replace(object_box(o), T=before[o.name]) for o in self.scene.objects if o.name != held)
            guides.append(_Guide(len(phases), guided, dict(openings), standing, held, T_tool_obj))
            down = np.vstack([guided, np.array(up[-2::-1]).reshape(-1, self.model.nq), q_k[None]])
            if a.name == Kind.TAKE_KNOB:
                phases.append(Phase(down, None, knob=a.obj, action=k))
                q_prev = q_k
                continue
            if a.name == Kind.PICK:
                phases.append(Phase(down, None, grasp=a.obj, action=k))
                held = a.obj
                T_tool_obj = np.linalg.inv(self.model.fk(q_k, self.tool)) @ kf.object_poses[k][a.obj]
            else:
                phases.append(Phase(down, held, release=a.obj, fall=a.name == Kind.DROP, action=k))
                held, T_tool_obj = None, None
            phases.append(Phase(np.vstack([q_k[None], np.array(up)]), held))  # leave vertically
            q_prev = q_pre
        self.rg.drawers({c: 0.0 for c in self.drawers})
        self.checker.set_objects([])
        return phases, guides

