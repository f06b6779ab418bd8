"""Initial guesses for the keyframe NLP (``nlp.keyframes``): a start z (n,) per keyframe, ReachIK's
coordinates (the base's x y [m] and yaw [rad] in the world plane, then the manipulator's joints).

Each start of ``solve_keyframes`` (``attempt_guess``) puts every keyframe whose hand goes to a target
x (3,) [m, world] at position IK from either a reachability-graph node near x (``graph_seed``: the
node's base pushed out of the footprints, ``push_free``; the nodes nearest the previous keyframe's
base first) or, on odd starts or when the graph has no new node, a random base heading whose base
stands off the footprints. Footprints are rectangles (T_world_rect (4, 4), full size [m]: fixtures,
open drawers) the base's circles keep off (``base_free``). A box pick turns the wrist so that the
fingers close across the faces away from a near neighbour (``face_roll``), and every other start turns
it a quarter more. A keyframe that follows a drawer is the previous one, the base shifted with it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING

import numpy as np

from rlgp_exec.planning.actions import Kind
from rlgp_exec.planning.detour import rect_distance
from rlgp_exec.planning.drawers import DrawerView
from rlgp_exec.reach.ik import ReachIK, base_circles
from rlgp_exec.robot.model import FloatArray, RobotModel

if TYPE_CHECKING:
    from rlgp_exec.planning.nlp.action import Action

__all__ = ["attempt_guess", "base_free", "face_roll", "graph_seed", "push_free"]

SEED_LOOKAHEAD = 4  # graph seeds looked at past an attempt's rank for one not tried at that keyframe yet
SAME_SEED = 0.05  # [m, rad] an initial guess this close (every coordinate) to an earlier one is not tried again
NEIGHBOUR_NEAR = 0.15  # [m] an object this close (centres, in the plane) to a picked one sets the grasp's seed roll


def attempt_guess(
    attempt: int,
    *,
    model: RobotModel,
    ik: ReachIK,
    actions: Sequence[Action],
    targets: Sequence[FloatArray | None],
    footprints_at: Sequence[list[tuple[FloatArray, FloatArray]]],
    opening_at: Sequence[dict[str, float]],
    drawers: dict[str, DrawerView],
    poses: dict[str, FloatArray],
    objs: dict,
    z_start: FloatArray,
    seeds: Callable[[FloatArray], list[FloatArray]] | None,
    rng: np.random.Generator,
    keep: dict[int, FloatArray],
    tried: list[list[FloatArray]],
) -> list[FloatArray]:
    """The initial guess of start ``attempt`` (0, 1, ...): one z (n,) per keyframe. ``keep``: keyframes a
    partial restart keeps (taken as they are); a keyframe without a target (None in ``targets``: it
    follows the drawer) is the previous one with the base shifted along the drawer's axis by the change
    of opening [m] (``opening_at``); any other from position IK at its target x (3,) [m, world], seeded on
    even starts by the first reachability-graph node (``seeds``, ``graph_seed``) from the attempt's rank on
    whose IK seed is not within SAME_SEED of one in ``tried`` (the guesses used at each keyframe so far,
    which this appends to), else by a random base heading clear of the keyframe's ``footprints_at``. A
    box pick's wrist is turned by ``face_roll`` (neighbours: the other objects in ``poses``, T_world_obj);
    odd starts turn it a quarter more either way (``rng``). Draws from ``rng`` in keyframe order."""
    init: list[FloatArray] = []
    for k, x in enumerate(targets):
        if k in keep:
            init.append(keep[k])
            continue
        if x is None:  # follows the drawer: the previous keyframe, the base shifted along the axis
            a = actions[k]
            z_follow = init[-1].copy()
            moved_m = opening_at[k][a.obj] - opening_at[k - 1][a.obj]
            z_follow[:2] += moved_m * drawers[a.obj].axis_world[:2]
            init.append(z_follow)
            continue
        prev_xy = init[-1][:2] if init else z_start[:2]
        z = None
        if attempt % 2 == 0:  # a reachability-graph node near the target, shifted onto it: the first one
            # from this attempt's rank on whose IK seed was not tried at this keyframe already
            for i in range(attempt // 2, attempt // 2 + SEED_LOOKAHEAD):
                z_near = graph_seed(ik, x, seeds, footprints_at[k], i, prev_xy)
                if z_near is None:
                    break
                z_try = _ik_seed(ik, x, z_near, footprints_at[k])
                if not any(np.max(np.abs(z_try - z_old)) < SAME_SEED for z_old in tried[k]):
                    z = z_try
                    break
        if z is None:  # else a random free base heading
            z = _ik_seed(ik, x, ik.guess(x, _free_heading(ik, x, rng, footprints_at[k])), footprints_at[k])
        a = actions[k]
        if a.name == Kind.PICK and objs[a.obj].shape != "cylinder":  # fingers across the faces away from neighbours
            z = face_roll(model, ik, z, poses[a.obj], [T[:3, 3] for m, T in poses.items() if m != a.obj])
        if attempt % 2 == 1:  # the grasp's roll: a quarter turn of the wrist on every other start
            z[-1] = np.clip(z[-1] + math.pi / 2 * rng.choice([-1.0, 1.0]), ik.lo[-1], ik.hi[-1])
        tried[k].append(z.copy())
        init.append(z)
    return init


def _free_heading(ik: ReachIK, x: FloatArray, rng: np.random.Generator, rects, tries: int = 24) -> float:
    """A random base heading [rad] for reaching x whose initial base (``ik.guess``) stands off every
    footprint rectangle in ``rects`` ((T, size): fixtures, open drawers) by the base's radius; any
    heading if none does."""
    for _ in range(tries):
        yaw = rng.uniform(-math.pi, math.pi)
        if base_free(ik, ik.guess(x, yaw), rects):
            return yaw
    return rng.uniform(-math.pi, math.pi)


def graph_seed(
    ik: ReachIK, x: FloatArray, seeds, rects, i: int, base_xy: FloatArray | None = None
) -> FloatArray | None:
    """The i-th of ``seeds(x)`` (z (n,) near x) whose base stands off the footprints in ``rects`` (open
    drawers included), ordered by their base's distance [m] to ``base_xy`` (2,) (the previous
    keyframe's base: a keyframe on the near side of a table, not across it, keeps the guided path
    between them a straight transport), else as ``seeds`` gives them; None when there are not that many."""
    if seeds is None:
        return None
    free = [z for z in (push_free(ik, z0, rects) for z0 in seeds(x)) if z is not None]
    if base_xy is not None:
        free.sort(key=lambda z: float(np.linalg.norm(z[:2] - base_xy)))  # stable: ties keep the graph's order
    return free[i] if i < len(free) else None


def push_free(ik: ReachIK, z: FloatArray, rects, margin: float = 0.01, max_push: float = 0.3) -> FloatArray | None:
    """z with its base pushed straight out of the footprint rectangles its NLP footprint circles overlap
    (a graph node's base stands clear of the real, smaller mesh; one enclosing circle kept the PR2's
    square base 0.47 m from a table it faces at 0.33 m: no seed in front of the table), or None when
    that takes more than ``max_push`` [m] or does not clear them."""
    z = np.asarray(z, float).copy()
    start = z[:2].copy()
    for _ in range(4):
        if base_free(ik, z, rects, exact=True):
            return z if float(np.linalg.norm(z[:2] - start)) <= max_push else None
        c, s = math.cos(z[2]), math.sin(z[2])
        for cx, cy, r in base_circles(ik.model):
            p = z[:2] + np.array([c * cx - s * cy, s * cx + c * cy])
            for T, size in rects:
                local = T[:2, :2].T @ (p - T[:2, 3])
                half = np.asarray(size[:2]) / 2
                outside = np.maximum(np.abs(local) - half, 0.0)
                d = float(np.linalg.norm(outside))
                if d > r + margin / 2:
                    continue
                if d > 1e-9:  # outside: away from the nearest point
                    n_local = np.sign(local) * outside / d
                    push = r + margin - d
                else:  # centre inside: out across the nearest side
                    k = int(np.argmin(half - np.abs(local)))
                    n_local = np.zeros(2)
                    n_local[k] = 1.0 if local[k] >= 0 else -1.0
                    push = float(half[k] - abs(local[k])) + r + margin
                z[:2] += T[:2, :2] @ n_local * push
    return None


def base_free(ik: ReachIK, z: FloatArray, rects, exact: bool = False) -> bool:
    """The base of z stands off every footprint rectangle in ``rects``: by the radius of one circle round
    the whole footprint (for random starts: conservative, any heading), or, ``exact``, each of the NLP's
    footprint circles where z's heading (z[2]) puts it."""
    if not exact:
        radius = max(math.hypot(cx, cy) + r for cx, cy, r in base_circles(ik.model))
        return all(rect_distance(z[:2], T, size) > radius for T, size in rects)
    c, s = math.cos(z[2]), math.sin(z[2])
    centres = [(z[0] + c * cx - s * cy, z[1] + s * cx + c * cy, r) for cx, cy, r in base_circles(ik.model)]
    return all(rect_distance(np.array([x, y]), T, size) > r for x, y, r in centres for T, size in rects)


def _ik_seed(ik: ReachIK, x: FloatArray, z0: FloatArray, rects) -> FloatArray:
    """Position IK for x from z0, when its base stays off ``rects`` (the IK knows only the fixtures, not
    an open drawer); else z0 itself."""
    r = ik.solve(x, z0)
    z = ik.z_of(r.q)
    return z if r.ok and base_free(ik, z, rects) else z0


def face_roll(
    model: RobotModel, ik: ReachIK, z: FloatArray, T_obj: FloatArray, others: list[FloatArray]
) -> FloatArray:
    """z with the wrist's last joint turned so that the fingers close along the object's face axis (x or y of
    T_obj (4, 4)) more nearly square to the direction of its nearest neighbour (``others``: centres (3,) [m]),
    one within NEIGHBOUR_NEAR; z as it is when none is. Along the other axis the open fingers reach towards
    the neighbour (pick_place_pr2 seed 2: block_c 9 cm from block_a, 4 starts failed on that grasp)."""
    d = [o[:2] - T_obj[:2, 3] for o in others if np.linalg.norm(o[:2] - T_obj[:2, 3]) < NEIGHBOUR_NEAR]
    if not d:
        return z
    d_near = min(d, key=lambda v: float(np.linalg.norm(v)))
    d_near = d_near / max(float(np.linalg.norm(d_near)), 1e-9)
    want = min((T_obj[:2, 0], T_obj[:2, 1]), key=lambda ax: abs(float(ax @ d_near)))
    closing = np.asarray(ik.manip.closing, float)

    def misalign(zz: FloatArray) -> float:  # |sin| of the angle between the closing axis and +-want, in the plane
        c = model.fk(ik.q_of(zz), ik.tool)[:3, :3] @ closing
        return abs(float(c[0] * want[1] - c[1] * want[0])) / max(float(np.linalg.norm(c[:2])), 1e-9)

    best, best_m = z, misalign(z)
    for turn in np.linspace(-math.pi / 2, math.pi / 2, 13):  # the roll joint, in 15 degree steps (fingers: mod pi)
        zz = z.copy()
        zz[-1] = np.clip(z[-1] + turn, ik.lo[-1], ik.hi[-1])
        m = misalign(zz)
        if m < best_m - 1e-6:
            best, best_m = zz, m
    return best
