"""Goal pre-checks for the R-LGP loop: an invalid goal is named at once; a goal object that no keyframe
solution can grasp where it stands, or set down on its target, makes the task infeasible.

The geometric check runs after the first candidate fails at the geometric levels (a plan that works
pays nothing for it). It is a relaxation of every grasp and placement: for each goal object not yet
where the goal wants it, can the tool reach the object's top at all (position IK, no orientation), and
for an ``on`` goal, the point above the target's centre? No, from the graph's nearest nodes and eight
base headings: infeasible (up to the IK's local solver, which the reason names).
"""

from __future__ import annotations

import logging
import math

import numpy as np

from rlgp_exec.planning.gripper_limits import gripper_limits, min_graspable_height
from rlgp_exec.planning.margins import RELEASE_CLEARANCE
from rlgp_exec.planning.nlp.action import target_surface
from rlgp_exec.planning.symbolic.model import GroundProblem
from rlgp_exec.planning.validate import goal_holds
from rlgp_exec.reach.ik import ReachIK, arm_spheres
from rlgp_exec.robot.config import load_robot_config
from rlgp_exec.scene import Scene
from rlgp_exec.scene.rules import SIZE_MIN

__all__ = ["goal_manipulator", "moved_objects", "physical_refusals", "unreachable_goal"]

log = logging.getLogger(__name__)
TOOL_ROOM = 0.001  # [m] above the tool sphere's radius, for the IK's tolerance


def goal_manipulator(scene: Scene) -> str:
    """The manipulator the planners use (the robot's first)."""
    return load_robot_config(scene.robot.name).manipulators[0].name


def _reachable(ik: ReachIK, x: np.ndarray, seeds: list[np.ndarray], starts: int = 8) -> bool:
    """Can the tool reach the point x (3,) [m] at all: position IK (Eq. 2: no orientation; the base only
    kept off the fixtures' footprints, the arm spheres out of them, as every keyframe must), warm-started
    from ``seeds`` (the reachability graph's nearest nodes) and from ``starts`` base headings. No
    PyBullet check: an IK answer's arbitrary hand would hit what a real grasp avoids, and a relaxation
    must not reject what the keyframe NLP could solve."""
    inits = [*seeds, *(ik.guess(x, 2 * math.pi * k / starts) for k in range(starts))]
    return any(ik.solve(x, z0).ok for z0 in inits)


def unreachable_goal(geo, problem: GroundProblem) -> str | None:
    """Why the goal is infeasible (a goal object the hand cannot reach, or a target it cannot reach
    holding it), or None."""
    scene = geo.scene
    ik = ReachIK(geo.model, scene, geo.q0, clearance=0.0)  # no base margin: looser than any keyframe
    # the IK keeps its tool sphere out of the fixtures, which the fingers round a flat object need not: the
    # point it aims at is that sphere's radius above the surface at least (a 3 cm disc: 5 mm higher)
    r_tool = max((r for f, r in arm_spheres(geo.model, ik.manip.name) if f == ik.tool), default=0.0)
    for atom in sorted(problem.goal - problem.init):
        if atom[0] not in ("on", "in"):
            continue
        o = scene.object(atom[1])
        lift = max(0.0, r_tool + TOOL_ROOM - o.size[2])
        top = np.asarray(o.pose[:3], float) + np.array([0.0, 0.0, o.size[2] / 2 + lift])
        if not _reachable(ik, top, geo.rg.node_seeds(top, 5)):
            return f"infeasible: {o.name} cannot be reached where it is (no position IK reaches {top.round(3)} m)"
        if atom[0] == "on" and atom[2] not in problem_objects(scene):
            T, _, z = target_surface(scene, atom[2])
            above = np.array([T[0, 3], T[1, 3], z + o.size[2] + lift])
            if not _reachable(ik, above, geo.rg.node_seeds(above, 5)):
                where = f"no position IK reaches {above.round(3)} m"
                return f"infeasible: {atom[2]} cannot be reached to set {o.name} on it ({where})"
    return None


def problem_objects(scene: Scene) -> set[str]:
    return {o.name for o in scene.objects}


def moved_objects(scene: Scene) -> list[str]:
    """Objects the goal needs the hand to hold (name order): the held one, each one an ``on``/``in`` literal
    names that is not already where the literal wants it, and whatever rests on one of those (or on an
    object the goal stacks onto)."""
    poses = {o.name: o.T for o in scene.objects}
    openings = dict(scene.start.openings)
    out = {scene.start.held} if scene.start.held is not None else set()
    names = {o.name for o in scene.objects}
    cleared = set()  # objects whose tops must be free: what is moved, and an object stacked onto
    for lit in scene.goal.literals:
        if lit.predicate in ("on", "in") and not goal_holds(scene, lit, poses, openings)[0]:
            out.add(lit.args[0])
            cleared |= {lit.args[0]} | ({lit.args[1]} & names)
    on = {o.name: o.support for o in scene.objects}
    for o in scene.objects:  # what rests (through others) on one of them must be moved off it first
        x, seen = on[o.name], {o.name}
        while x in on and x not in seen:
            if x in cleared and o.name not in out:
                out.add(o.name)
                break
            seen.add(x)
            x = on[x]
    return sorted(out)


def physical_refusals(scene: Scene) -> list[tuple[str, str]]:
    """Why the robot's first hand cannot hold an object the goal moves, one reason per object and rule
    (``planning.gripper_limits``: its open width and its fingertips' reach, probed once per robot; the
    scene rules' SIZE_MIN for scenes not read by the loader) as (object, reason); empty when none applies."""
    limits = gripper_limits(scene.robot.name)
    robot = scene.robot.name
    low = min_graspable_height(limits)
    reasons = []
    for name in moved_objects(scene):
        o = scene.object(name)
        if min(o.size) < SIZE_MIN:
            reasons.append((name, f"{name} {list(o.size)} m: an extent below SIZE_MIN {SIZE_MIN} m"))
            continue
        width = min(o.size[:2])  # the grasp closes across either horizontal axis: the narrower one is best
        if width > limits.max_width_m:
            reasons.append((name,
                f"{name} is wider than the {robot}'s open gripper: its narrower side {width:.3f} m, the "
                f"fingers open {limits.open_width_m:.3f} m at the grasp depth, so at most "
                f"{limits.max_width_m:.3f} m fits with {RELEASE_CLEARANCE * 1000:g} mm each side"
            ))
        if o.size[2] < low:
            reasons.append((name,
                f"{name} is shorter than the {robot}'s grasp needs: {o.size[2]:.3f} m tall, at least "
                f"{low:.3f} m (the open fingertips reach {limits.tip_reach_m:.3f} m past the tool point, held "
                f"at most half the height below the top, {RELEASE_CLEARANCE * 1000:g} mm off the support)"
            ))
    return reasons
