"""What each planner can express, in one table, and the check both planners run before any search.

``CAPABILITIES`` is the single place that changes when a planner gains an action kind or starts to
drive a robot's base. ``refuse(scene, planner)`` raises ``TaskRefusedError`` (a ``SceneError``: the CLI's
exit 2) naming what the goal needs that the planner lacks and which planners have it, or a physical
impossibility (``feasibility.physical_refusals``), or, for a planner that keeps the base where it
starts, an object or target beyond a conservative bound on the arms' reach. It builds no graph and
solves no NLP.
"""

from __future__ import annotations

import functools
import itertools
import logging
from collections.abc import Iterable
from typing import NamedTuple

import numpy as np

from rlgp_exec.errors import RlgpError, SceneError
from rlgp_exec.planning.actions import ACTION_KINDS as _ALL_KINDS
from rlgp_exec.planning.actions import DRAWER_ACTIONS, GEOMETRIC_ACTIONS, GNPP_ACTIONS, MOVES, Kind
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene

__all__ = [
    "ACTION_KINDS",
    "CAPABILITIES",
    "DRAWER_KINDS",
    "ArmReach",
    "Capability",
    "ReachGap",
    "ReachSegment",
    "TaskRefusedError",
    "arm_reach",
    "beyond_reach",
    "capability",
    "needed_actions",
    "reach_segments",
    "refuse",
    "start_reach_gaps",
]

log = logging.getLogger(__name__)

#: the kinds a task may need (GNPP's base moves are its own means, never a task's need)
ACTION_KINDS = tuple(k.name for k in _ALL_KINDS if k.name not in MOVES)
DRAWER_KINDS = frozenset({*DRAWER_ACTIONS, Kind.DROP, Kind.PICK_FROM_DRAWER})
_ROBOTS = frozenset({"hsr", "pr2"})


class TaskRefusedError(SceneError):
    """A task refused before any search: the planner cannot express it, or the robot could not do it. A
    SceneError (the scene, as a task for this planner and robot, is bad input): the CLI exits 2 and the
    executive ends the task FAILED, as for a world it cannot plan in."""

    def __init__(self, scene: Scene, where: str, message: str) -> None:
        super().__init__(scene.source or scene.name, where, message)


class Capability(NamedTuple):
    actions: frozenset[str]  # action kinds of ACTION_KINDS its geometric layer realises
    drives_base: frozenset[str]  # robots whose base it moves between actions (else the base stays at the start)
    suggest: str  # the planner name a refusal suggests for this family


_RLGP = Capability(frozenset(GEOMETRIC_ACTIONS), _ROBOTS, "rlgp")  # R-LGP's layers read planning.actions
_GNPP = Capability(frozenset(GNPP_ACTIONS) - set(MOVES), _ROBOTS, "gnpp")

#: planner name -> what it can express; GNPP's variants share one entry
CAPABILITIES: dict[str, Capability] = {
    "rlgp": _RLGP,
    "lgp": _RLGP,
    **{v: _GNPP for v in ("gnpp_t", "gnpp_tr", "gnpp_trn", "gnpp_trng", "oneway")},
}


_LISTED = 3  # reasons a refusal lists at most: the message stays one readable line


def _listed(reasons: list[str]) -> str:
    more = f"; and {len(reasons) - _LISTED} more" if len(reasons) > _LISTED else ""
    return "; ".join(reasons[:_LISTED]) + more


def capability(planner: str) -> Capability:
    """The planner's entry; raises RlgpError naming the valid planners if it has none."""
    try:
        return CAPABILITIES[planner]
    except KeyError:
        raise RlgpError(f"no capability entry for planner {planner!r}; valid: {list(CAPABILITIES)}") from None


def needed_actions(scene: Scene) -> dict[str, str]:
    """Action kind -> the first goal literal (or start) that needs it, for the goal's literals that do not
    hold at the start."""
    # local: planning.symbolic.problem and planning.validate bring CasADi and PyBullet
    from rlgp_exec.planning.symbolic.problem import problem_from_scene
    from rlgp_exec.planning.validate import goal_holds

    types = dict(problem_from_scene(scene).objects)
    poses = {o.name: o.T for o in scene.objects}
    openings = dict(scene.start.openings)
    need: dict[str, str] = {}

    def add(kinds: Iterable[str], why: str) -> None:
        for k in kinds:
            need.setdefault(k, why)

    def to_cabinet(cab: str, why: str) -> None:  # the drawer must be open to reach in
        if scene.start.opening(cab) <= 0.0:
            add((Kind.TAKE_KNOB, Kind.OPEN_DRAWER), why)

    for lit in scene.goal.literals:
        if goal_holds(scene, lit, poses, openings)[0]:
            continue
        text = f"({lit.predicate} {' '.join(lit.args)})"
        if lit.predicate in ("on", "in"):
            o = scene.object(lit.args[0])
            if o.support.endswith(".drawer"):
                add((Kind.PICK_FROM_DRAWER,), f"{text}: {o.name} starts in a drawer")
                to_cabinet(o.support.removesuffix(".drawer"), f"{text}: {o.name} starts in a closed drawer")
            elif o.name != scene.start.held:
                add((Kind.PICK,), text)
        if lit.predicate == "on":
            add((Kind.STACK,) if types.get(lit.args[1]) in ("movable", "slot") else (Kind.PLACE,), text)
        elif lit.predicate == "in":
            add((Kind.DROP,), text)
            to_cabinet(lit.args[1], text)
        elif lit.predicate == "open":
            add((Kind.TAKE_KNOB, Kind.OPEN_DRAWER), text)
        elif lit.predicate == "closed":
            add((Kind.TAKE_KNOB, Kind.CLOSE_DRAWER), text)
    return need


class ArmReach(NamedTuple):
    """How far an arm's tool point can get from its first joint's origin (``arm_reach``)."""

    manipulator: str
    first_joint: str
    reach_m: float  # [m] the bound on the distance from the (slid) first joint's origin
    #: [m] a prismatic first joint's travel from its home value along its axis (e.g. the HSR's lift), (0, 0)
    #: for a revolute one: the bound holds round every point of that segment
    slide_m: tuple[float, float] = (0.0, 0.0)


@functools.cache
def arm_reach(robot: str) -> tuple[ArmReach, ...]:
    """Per arm, a bound on where its tool point can be: the sum of the distances between its joints'
    origins and the tool frame at the home pose, round the first joint's origin. No configuration puts the
    tool point further from it (the triangle inequality), whatever the joints do; a prismatic first joint
    slides that origin along its axis (``ArmReach.slide_m``). Any other prismatic joint adds its travel."""
    model = load_robot(robot)
    q = model.home()
    by_name = {j.name: j for j in model.urdf.joints}
    out = []
    for man in model.config.manipulators:
        idx = list(model.group(man.group))
        names = [model.joint_names[i] for i in idx]
        pts = [T[:3, 3] for T in model.fk_many(q, [*names, man.tool_frame])]
        reach = float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(pts)))
        slide = (0.0, 0.0)
        for k, (i, n) in enumerate(zip(idx, names, strict=True)):
            j = by_name[n]
            if j.type != "prismatic":
                continue
            lo, hi = float(model.limits.lower[i] - q[i]), float(model.limits.upper[i] - q[i])
            if k == 0:
                slide = (lo, hi)
            else:
                reach += max(abs(lo), abs(hi))
        out.append(ArmReach(man.name, names[0], reach, slide))
    return tuple(out)


class ReachSegment(NamedTuple):
    """Where one arm's tool point can be at a configuration: within ``reach_m`` [m] of the segment
    ``start``-``end`` (3,) [m, world] that its first joint's origin covers (``arm_reach``)."""

    manipulator: str
    start: FloatArray
    end: FloatArray
    reach_m: float

    @property
    def middle(self) -> FloatArray:
        return 0.5 * (self.start + self.end)

    def gap_m(self, point: FloatArray) -> float:
        """[m] how far ``point`` (3,) lies past the bound (<= 0: maybe reachable)."""
        d = self.end - self.start
        u = 0.0 if not d.any() else float(np.clip((point - self.start) @ d / (d @ d), 0.0, 1.0))
        return float(np.linalg.norm(point - (self.start + u * d))) - self.reach_m


def reach_segments(model: RobotModel, q: FloatArray, manipulator: str | None = None) -> tuple[ReachSegment, ...]:
    """Per arm (``arm_reach``'s order; only ``manipulator``'s if given), its ``ReachSegment`` at the full
    configuration q: the first joint's origin there, slid over a prismatic first joint's whole travel
    (from q's value of it)."""
    out = []
    for a in arm_reach(model.config.name):
        if manipulator is not None and a.manipulator != manipulator:
            continue
        origin = model.fk(q, a.first_joint)[:3, 3]
        start = end = origin
        if a.slide_m != (0.0, 0.0):  # a prismatic joint translates its child frame along its axis
            i = model.index(a.first_joint)
            dq = np.zeros(model.nq)
            dq[i] = 1e-3
            axis = (model.fk(np.asarray(q) + dq, a.first_joint)[:3, 3] - origin) / 1e-3
            start = origin + float(model.limits.lower[i] - q[i]) * axis
            end = origin + float(model.limits.upper[i] - q[i]) * axis
        out.append(ReachSegment(a.manipulator, start, end, a.reach_m))
    return tuple(out)


class ReachGap(NamedTuple):
    """An object to be moved (``target`` None), or the goal target it is to be put on, that no arm reaches
    from the start base: the least distance [m] past every arm's ``arm_reach`` bound."""

    obj: str
    target: str | None
    gap_m: float

    def __str__(self) -> str:
        if self.target is None:
            return f"{self.obj} is {self.gap_m:.2f} m beyond"
        return f"{self.target} (the target of {self.obj}) is {self.gap_m:.2f} m beyond"


def start_reach_gaps(scene: Scene) -> list[ReachGap]:
    """The objects to be moved, and the goal targets ("on") they go to, that no arm reaches from the start
    base within ``arm_reach``'s bound: a grasp point is an object's top centre; a target's is the top of
    the object put on it at the target's point nearest the arm. Sound: each gap proves that no hand gets
    there while the base stays at its start (an empty list does not prove that it serves). A goal naming
    an object the scene lacks has no reach to bound (the planners name it as an invalid goal): none."""
    # local: planning.feasibility and planning.nlp.action bring SciPy and OpenCV
    from rlgp_exec.planning.feasibility import moved_objects
    from rlgp_exec.planning.nlp.action import target_surface

    names = {o.name for o in scene.objects}
    if any(lit.args[0] not in names for lit in scene.goal.literals if lit.predicate in ("on", "in")):
        return []
    moved = moved_objects(scene)
    model = load_robot(scene.robot.name)
    arms = reach_segments(model, model.home(scene.robot.base, scene.robot.joints))

    def gap(point_of) -> float | None:  # the least distance past the reach, None when some arm reaches
        gaps = [a.gap_m(point_of(a.middle)) for a in arms]
        return None if min(gaps) <= 0.0 else min(gaps)

    def top(name: str, height: float = 0.0):
        o = scene.object(name)
        return lambda s: np.asarray(o.pose[:3], float) + np.array([0.0, 0.0, o.size[2] / 2 + height])

    out = []
    for name in moved:
        if name == scene.start.held:
            continue
        g = gap(top(name))
        if g is not None:
            out.append(ReachGap(name, None, g))
    for lit in scene.goal.literals:
        if lit.predicate != "on" or lit.args[0] not in moved:
            continue
        target, h = lit.args[1], scene.object(lit.args[0]).size[2]
        if target in names:
            g = gap(top(target, h))
        else:
            T, (hx, hy), z = target_surface(scene, target)

            def nearest(s, T=T, hx=hx, hy=hy, z=z + h):  # the target rectangle's point nearest the arm
                local = T[:2, :2].T @ (s[:2] - T[:2, 3])
                xy = T[:2, :2] @ np.clip(local, [-hx, -hy], [hx, hy]) + T[:2, 3]
                return np.array([xy[0], xy[1], z])

            g = gap(nearest)
        if g is not None:
            out.append(ReachGap(lit.args[0], target, g))
    return out


def beyond_reach(scene: Scene) -> list[str]:
    """Why the scene's task cannot be done from the start base (``start_reach_gaps``, as text)."""
    return [str(g) for g in start_reach_gaps(scene)]


def refuse(scene: Scene, planner: str) -> None:
    """Raise TaskRefusedError if ``planner`` cannot express the scene's goal or no hand can do it (see the module)."""
    # local: planning.feasibility and planning.symbolic.errors bring SciPy, OpenCV and CasADi
    from rlgp_exec.planning.feasibility import physical_refusals
    from rlgp_exec.planning.symbolic.errors import SymbolicError

    cap = capability(planner)
    try:
        needed = needed_actions(scene)
    except SymbolicError:  # a goal the symbolic layer cannot state: the planner names it as an invalid goal
        return
    # what no planner could do first: an object too wide for the hand also changes how the goal is typed
    physical = physical_refusals(scene)
    if physical:
        raise TaskRefusedError(scene, f"[[object]] '{physical[0][0]}'.size",
                               f"cannot be done by the {scene.robot.name}: " + _listed([r for _, r in physical]))
    missing = {k: why for k, why in needed.items() if k not in cap.actions}
    if missing:
        drawer = set(missing) <= DRAWER_KINDS
        what = "no drawer actions" if drawer else f"no {'/'.join(sorted(missing))} action"
        able = sorted({c.suggest for c in CAPABILITIES.values() if set(missing) <= c.actions})
        use = f"use --planner {' or '.join(able)}" if able else "no planner here has them all"
        needs = "; ".join(f"{k} for {why}" for k, why in missing.items())
        raise TaskRefusedError(scene, "[goal]", f"{planner}: {what} ({needs}); {use}")
    if scene.robot.name not in cap.drives_base:
        far = beyond_reach(scene)
        if far:
            able = sorted({c.suggest for c in CAPABILITIES.values() if scene.robot.name in c.drives_base
                           and set(needed) <= c.actions})
            use = (f"{' and '.join(able)} drive{'s' if len(able) == 1 else ''} the base: use --planner {able[0]}"
                   if able else "no planner here drives its base with these actions")
            reach = ", ".join(f"{a.manipulator} {a.reach_m:.2f} m" for a in arm_reach(scene.robot.name))
            raise TaskRefusedError(scene, "[robot].base",
                                   f"{planner}: keeps the {scene.robot.name}'s base at its start, where its arms "
                                   f"reach at most {reach} from their first joints: " + _listed(far) + f"; {use}")
    log.debug("%s: %s accepted", planner, scene.name)
