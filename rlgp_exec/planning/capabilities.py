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
from rlgp_exec.scene import Scene

__all__ = [
    "ACTION_KINDS",
    "CAPABILITIES",
    "DRAWER_KINDS",
    "Capability",
    "TaskRefusedError",
    "arm_reach",
    "beyond_reach",
    "capability",
    "needed_actions",
    "refuse",
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


@functools.cache
def arm_reach(robot: str) -> tuple[tuple[str, str, float], ...]:
    """(manipulator, first arm joint, reach [m]) per arm: the sum of the distances between its joints'
    origins and the tool frame, at the home pose. No configuration puts the tool point further from the
    first joint's origin (the triangle inequality), whatever the joints do."""
    model = load_robot(robot)
    q = model.home()
    out = []
    for man in model.config.manipulators:
        names = [model.joint_names[i] for i in model.group(man.group)]
        pts = [T[:3, 3] for T in model.fk_many(q, [*names, man.tool_frame])]
        out.append((man.name, names[0], float(sum(np.linalg.norm(b - a) for a, b in itertools.pairwise(pts)))))
    return tuple(out)


def _out_of_reach(scene: Scene, moved: list[str]) -> list[str]:
    """Objects (and goal targets) no arm reaches from the start base, within ``arm_reach``'s bound."""
    # local: planning.nlp.action brings SciPy and OpenCV
    from rlgp_exec.planning.nlp.action import target_surface

    model = load_robot(scene.robot.name)
    q0 = model.home(scene.robot.base, scene.robot.joints)
    arms = arm_reach(scene.robot.name)
    shoulders = [(model.fk(q0, j)[:3, 3], r) for _, j, r in arms]

    def far(point_of) -> float | None:  # the least distance past the reach, None when some arm reaches
        gaps = [float(np.linalg.norm(point_of(s) - s)) - r for s, r in shoulders]
        return None if min(gaps) <= 0.0 else min(gaps)

    def top(name: str):
        o = scene.object(name)
        return lambda s: np.asarray(o.pose[:3], float) + np.array([0.0, 0.0, o.size[2] / 2])

    reasons = []
    for name in moved:
        if name == scene.start.held:
            continue
        gap = far(top(name))
        if gap is not None:
            reasons.append(f"{name} is {gap:.2f} m beyond")
    for lit in scene.goal.literals:
        if lit.predicate != "on" or lit.args[0] not in moved:
            continue
        target = lit.args[1]
        if target in {o.name for o in scene.objects}:
            gap = far(top(target))
        else:
            T, (hx, hy), z = target_surface(scene, target)

            def nearest(s, T=T, hx=hx, hy=hy, z=z):  # the target rectangle's point nearest the shoulder
                local = T[:2, :2].T @ (s[:2] - T[:2, 3])
                xy = T[:2, :2] @ np.clip(local, [-hx, -hy], [hx, hy]) + T[:2, 3]
                return np.array([xy[0], xy[1], z])

            gap = far(nearest)
        if gap is not None:
            reasons.append(f"{target} (the target of {lit.args[0]}) is {gap:.2f} m beyond")
    return reasons


def beyond_reach(scene: Scene) -> list[str]:
    """Why the scene's task cannot be done from the start base: each object to be moved, and each goal
    target, that no arm reaches from there within ``arm_reach``'s bound (a sound bound: an empty list does
    not prove that the start base serves, a reason proves that it does not). A goal naming an object the
    scene lacks has no reach to bound (the planners name it as an invalid goal): none."""
    # local: planning.feasibility brings SciPy and OpenCV
    from rlgp_exec.planning.feasibility import moved_objects

    names = {o.name for o in scene.objects}
    if any(lit.args[0] not in names for lit in scene.goal.literals if lit.predicate in ("on", "in")):
        return []
    return _out_of_reach(scene, moved_objects(scene))


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
            reach = ", ".join(f"{m} {r:.2f} m" for m, _, r in arm_reach(scene.robot.name))
            raise TaskRefusedError(scene, "[robot].base",
                                   f"{planner}: keeps the {scene.robot.name}'s base at its start, where its arms "
                                   f"reach at most {reach} from their first joints: " + _listed(far) + f"; {use}")
    log.debug("%s: %s accepted", planner, scene.name)
