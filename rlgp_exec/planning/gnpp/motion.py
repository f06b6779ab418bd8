"""From a feasible graph-NLP to joint paths the executive can run (and the replay can check).

The keyframes are the solved arm configurations at each action. Between them each action is one
phase of straight joint-space segments: every arm left at a keyframe first lifts its hand
``LIFT`` straight up (``LIFT_STEPS`` rows on a vertical line, the tool's orientation kept); every
other arm then returns to its start posture (one that holds an object takes it along); the acting arm
moves to ``LIFT`` above its keyframe, then down onto it along the same vertical line (grasp or
release). A mobile arm's ``end-move`` is the drive to the base of the next keyframes
(``start-move`` lifts the hand; with arms riding the same base, every arm goes to its start posture
there, the base kept, as the other arms do before an action): the arm held in one posture (its own,
folded with an empty hand, or raised), the base straight if that motion is free, else round the
fixtures by OMPL on the base alone,
each motion checked in PyBullet with the resting objects and the held one (``reach.ompl_plan.drive_base``,
as R-LGP drives). Each acting arm's move to its approach configuration is also returned as a
``Transit``: the straight motion the paper's trajectory stage re-optimises (``gnpp.trajectory``); so is
each idle arm's move home (``Transit.home``): a straight joint move from above what it just let go of or
picked can sweep its fingers, or the object it holds, through a block (seen in the replay on tower_pr2).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import replace
from typing import NamedTuple

import numpy as np

from rlgp_exec.planning.actions import Kind
from rlgp_exec.planning.gnpp.drawer_motion import APPROACH, DRIVES, DrawerState, along_axis
from rlgp_exec.planning.gnpp.geometry import FLOOR, LIFT, FactorLib
from rlgp_exec.planning.gnpp.guess import TopIK, rel_T
from rlgp_exec.planning.gnpp.pntc import MOVES, Var
from rlgp_exec.planning.symbolic.model import GroundAction
from rlgp_exec.planning.validate import Phase
from rlgp_exec.reach import WorldChecker
from rlgp_exec.reach.ompl_plan import drive_base, drive_postures
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene.geometry import object_box

__all__ = ["CARRY", "LIFT", "Transit", "carry_q", "phases_of", "place", "world_checker"]

LIFT_STEPS = 5  # rows of a lift (2 cm apart): straight up in the world, not only in joint space
LIFT_NEWTON = 20  # damped least-squares iterations per row at most
LIFT_TOL = 1e-3  # [m, rad] a lift row's largest position or orientation error
CARRY = (0.40, 0.20, 0.10)  # [m] the carrying tool ahead of, outwards of and below the arm's first joint
DRIVE_TIMEOUT = 2.0  # [s] OMPL's time for a base path round the fixtures (per posture tried)


class Transit(NamedTuple):
    """An arm's straight move between two rows of a phase's path (``row`` -> ``row + 1``): an acting arm's
    from where the plan left it to ``LIFT`` above its next keyframe, or (``home``) an idle arm's from
    ``LIFT`` above its last keyframe to its start posture; the other arms stand still meanwhile."""

    phase: int  # index into the phases
    row: int  # the move's first row in the phase's path
    arm: str
    held: tuple[str, FloatArray] | None  # (object, T_tool_obj (4, 4)) the arm carries
    resting: dict[str, FloatArray]  # the objects in no hand: world pose (4,) [x, y, z, yaw]
    home: bool = False  # an idle arm's move to its start posture (out of the acting arm's way)


def _straight_up(lib: FactorLib, arm: str, q: FloatArray) -> list[FloatArray] | None:
    """The arm's variables (``LIFT_STEPS`` rows, ``q`` excluded) that raise its tool ``LIFT`` straight up
    in the world frame in equal steps, the tool's orientation kept (damped least squares on the arm's
    joints, a mobile base held); None if a step misses by more than ``LIFT_TOL`` or leaves the joint
    limits, or the top one breaks ``ColFix`` (the fixtures; on the PR2 also its wrist-flex bound: a
    wrist flexed further folds the fingers onto the forearm, seen in the replay when this was left out)."""
    model, tool = lib.model, lib.model.manipulator(arm).tool_frame
    idx = lib.arm_index(arm)
    cols = idx[3:] if lib.mobile else idx  # the joints that move: not a mobile arm's base
    lo, hi = lib.var_bounds("q", arm)
    full = lib.full_q({arm: q})
    T0 = model.fk(full, tool)
    rows = []
    for i in range(1, LIFT_STEPS + 1):
        target = T0[:3, 3] + np.array([0.0, 0.0, LIFT * i / LIFT_STEPS])
        for _ in range(LIFT_NEWTON):
            T = model.fk(full, tool)
            err = np.r_[target - T[:3, 3], 0.5 * (np.cross(T[:3, 0], T0[:3, 0]) + np.cross(T[:3, 1], T0[:3, 1])
                                                  + np.cross(T[:3, 2], T0[:3, 2]))]
            if np.abs(err).max() < 1e-5:
                break
            J = model.jacobian(full, tool)[:, cols]
            full[cols] += J.T @ np.linalg.solve(J @ J.T + 1e-8 * np.eye(6), err)
        qa = full[idx]
        if np.abs(err).max() > LIFT_TOL or np.any(qa < lo - 1e-9) or np.any(qa > hi + 1e-9):
            return None
        rows.append(qa.copy())
    col = lib.factor(("ColFix", arm))
    g = np.asarray(col.fn(rows[-1])).reshape(-1)
    if np.any(g < col.lower - 1e-6) or np.any(g > col.upper + 1e-6):
        return None
    return rows


def _lift(lib: FactorLib, ik: TopIK, arm: str, q: FloatArray) -> list[FloatArray] | None:
    """The arm's variables that raise its tool ``LIFT`` above where ``q`` has it, ``q`` excluded: straight
    up with the orientation kept (``_straight_up``: the open fingers slide off what they let go of or
    onto what they grasp), else one IK solution (``TopIK``, approach vertical), else None."""
    rows = _straight_up(lib, arm, q)
    if rows is not None:
        return rows
    pos = lib.tool_T(arm, q)[:3, 3] + np.array([0.0, 0.0, LIFT])
    ok, q_up = ik.solve(arm, pos, q, fixed_base=True)
    return [q_up] if ok else None


def carry_q(lib: FactorLib, ik: TopIK, arm: str) -> FloatArray | None:
    """The arm's variable in its carrying posture, or None: where an idle arm that holds an object waits
    while the other acts or the base drives, on a robot whose arms share a driven base (the PR2's start
    posture is the tuck, the arms interlocked a centimetre apart: it holds nothing, and an arm leaving it
    or coming back sweeps through the other). The tool ``CARRY`` ahead of, beside and below the arm's
    first joint at the start base, approach down (``TopIK``: clear of the fixtures there); None on other
    robots or if no such posture is found. Solved once per ``ik``."""
    if not (lib.mobile and lib.riders):
        return None
    memo = ik.carry
    if arm not in memo:
        model, q0 = lib.model, lib.q_nominal
        first = model.joint_names[model.group(model.manipulator(arm).group)[0]]
        T_shoulder, T_base = model.fk_many(q0, [first, "base_link"])  # pinocchio names a joint's frame after it
        side = 1.0 if (np.linalg.inv(T_base) @ T_shoulder)[1, 3] > 0 else -1.0
        ahead, out, down = CARRY
        pos = T_shoulder[:3, 3] + T_base[:3, :3] @ np.array([ahead, side * out, -down])
        ok, q_ik = ik.solve(arm, pos, lib.home_q(arm), fixed_base=True)
        memo[arm] = q_ik if ok else None
    q = memo[arm]
    return None if q is None else q.copy()


def world_checker(
    lib: FactorLib, arm: str, resting: Mapping[str, FloatArray], held: tuple[str, FloatArray] | None,
    openings: Mapping[str, float] | None = None,
):
    """A ``reach.WorldChecker`` for ``arm``'s motions: the objects at ``resting`` world poses (4,) as
    obstacles, ``held`` = (object, T_tool_obj (4, 4)) in its hand, the drawers at ``openings`` [m] (None:
    closed). The caller closes it."""
    checker = WorldChecker(lib.scene, lib.model.manipulator(arm).group, manipulator=arm)
    if openings:
        checker.set_drawers(dict(openings))
    place(checker, lib, resting, held)
    return checker


def place(checker, lib: FactorLib, resting: Mapping[str, FloatArray], held: tuple[str, FloatArray] | None) -> None:
    """``checker``'s obstacles the objects at ``resting`` (replacing earlier ones), ``held`` in the hand (or none)."""
    checker.set_objects([replace(object_box(lib.objects[o]), T=lib.object_T(w)) for o, w in resting.items()])
    if held is not None:
        checker.attach(np.asarray(lib.objects[held[0]].size), held[1])
    else:
        checker.detach()


def _drive(
    lib: FactorLib,
    arm: str,
    q1: FloatArray,
    base: FloatArray,
    resting: Mapping[str, FloatArray],
    held: tuple[str, FloatArray] | None,
    openings: Mapping[str, float] | None = None,
) -> FloatArray | None:
    """A checked path (n, nq) from the full configuration q1 to ``arm``'s base pose ``base`` (3,) [m, rad]
    (the arm in one of ``drive_postures``), the objects at ``resting`` world poses (4,) as obstacles,
    ``held`` = (object, T_tool_obj (4, 4)) carried; None if no posture gives one."""
    model = lib.model
    checker = world_checker(lib, arm, resting, held, openings)
    try:
        q2 = q1.copy()
        q2[list(model.group("base"))] = base
        rigid, postures = drive_postures(model, q1, q2, empty_hand=held is None)
        lo = np.full(2, -FLOOR)
        hi = np.full(2, FLOOR)
        return drive_base(checker, q1, q2, rigid, postures, lo, hi, DRIVE_TIMEOUT)
    finally:
        checker.close()


def phases_of(
    lib: FactorLib, ik: TopIK, actions: Sequence[GroundAction], values: Mapping[Var, FloatArray]
) -> tuple[tuple[Phase, ...], FloatArray, tuple[Transit, ...]] | str:
    """(phases, keyframes (n, nq), the acting arms' transits) or the reason no path could be laid out."""
    arms = lib.arms
    cur = {m: lib.home_q(m) for m in arms}
    low = dict.fromkeys(arms, False)
    holding: dict[str, str] = {}
    phases: list[Phase] = []
    keyframes = []
    transits: list[Transit] = []
    drawers = DrawerState.start(lib)  # the openings and what is in the drawers, before each action

    def full() -> FloatArray:
        return lib.full_q(cur)

    def grip_of(arm: str, k: int) -> tuple[str, FloatArray] | None:
        """(object, T_tool_obj (4, 4)) ``arm`` holds before action ``k`` (0-based), None if empty."""
        obj = holding.get(arm)
        return None if obj is None else (obj, rel_T(values[Var("x", obj, k)], lib.upright(arm)))

    def resting_at(k: int) -> dict[str, FloatArray]:
        """The objects in no hand before action ``k`` (0-based): world pose (4,) [x, y, z, yaw]."""
        return {o: drawers.world(lib, o, values, k) for o in lib.objects if o not in holding.values()}

    def home(arm: str) -> FloatArray:
        """The arm's start posture where the base now stands; holding an object, its carrying posture
        (``carry_q``) where there is one."""
        carry = carry_q(lib, ik, arm) if arm in holding else None
        q = lib.home_q(arm) if carry is None else carry
        if lib.mobile:
            q[:3] = cur[arm][:3]
        return q

    def lift_low(path: list[FloatArray], active: str | None, where: str, k: int, all_home: bool = False) -> str | None:
        """Raise every arm left down at its last keyframe (appending to ``path``); with an ``active`` arm
        about to act (action ``k``, 0-based), the other idle arms also go home (``all_home``: every arm),
        each move a ``Transit`` (``home``). The reason on failure."""
        for arm in arms:
            if low[arm]:
                up = _lift(lib, ik, arm, cur[arm])
                if up is None:
                    return f"cannot lift {arm} after {where}"
                for row in up:
                    cur[arm] = row
                    path.append(full())
                low[arm] = False
            if active is not None and (arm != active or all_home) and not np.array_equal(cur[arm], home(arm)):
                # out of the active arm's way, with what it holds: the graph-NLP kept the arms apart
                # at the keyframes only, not along the approach
                transits.append(Transit(len(phases), len(path) - 1, arm, grip_of(arm, k), resting_at(k), home=True))
                cur[arm] = home(arm)
                path.append(full())
        return None

    for k, a in enumerate(actions):
        m = a.args[0]
        v = Var("q", m, k + 1)
        if v not in values:
            return f"no keyframe for {a}"
        path = [full()]
        # arms sharing the base all go to their start posture before it moves: the drive holds one posture
        # (``drive_postures``: one arm's), and an arm left stretched out would sweep across the fixtures
        shared = bool(lib.riders) and a.name == MOVES[0]
        why = lift_low(path, m, f"its last action (before {a})", k, all_home=shared)
        if why is not None:
            return why
        obj = holding.get(m)
        carried = tuple((arm, o) for arm, o in holding.items() if arm != m)
        if a.name in MOVES:
            if a.name == MOVES[1]:  # end-move: drive to the base of the keyframes that follow
                still = [o for o in lib.objects if o not in holding.values()]
                resting = {o: drawers.world(lib, o, values, k + 1) for o in still}
                grip = None if obj is None else (obj, rel_T(values[Var("x", obj, k + 1)], lib.upright(m)))
                drive = _drive(lib, m, full(), values[v][:3], resting, grip, drawers.openings)
                if drive is None:
                    return f"no collision-free drive for {a} to base {np.round(values[v][:3], 3).tolist()}"
                path += list(drive[1:])
                for arm in arms:  # every arm's variable carries the base
                    cur[arm] = drive[-1][lib.arm_index(arm)]
            phases.append(Phase(np.array(path), obj, arm=m, carried=carried, action=k))
            keyframes.append(full())
            continue
        if a.name in DRIVES:  # the hand on the knob drives the drawer, lets go and backs off along its axis
            c = a.args[1]
            cur[m] = values[v]
            phases.append(Phase(np.array([*path, full()]), None, knob=c, drives_drawer=True, arm=m,
                                carried=carried, action=k))
            keyframes.append(full())
            cur[m] = along_axis(lib, c, values[v], APPROACH)
            leave = [keyframes[-1], full()]
            if lib.mobile:  # then the arm folds to its start posture: a drive from a hand held out at a knob's
                cur[m] = np.r_[cur[m][:3], lib.home_q(m)[3:]]  # height meets what stands at its end
                leave.append(full())
            phases.append(Phase(np.array(leave), None, knob=c, arm=m, carried=carried))
            drawers.after(lib, a)
            continue
        if a.name == Kind.TAKE_KNOB:  # onto the knob along the drawer's axis, from APPROACH out
            c, q_k = a.args[1], values[v]
            resting = {o: drawers.world(lib, o, values, k) for o in lib.objects if o not in holding.values()}
            transits.append(Transit(len(phases), len(path) - 1, m, None, resting))
            for row in (along_axis(lib, c, q_k, APPROACH), q_k):
                cur[m] = row
                path.append(full())
            keyframes.append(full())
            phases.append(Phase(np.array(path), None, knob=c, arm=m, carried=carried, action=k))
            continue  # the hand stays on the knob (not lifted): the drive starts there
        obj = a.args[1]
        q_k = values[v]
        up = _lift(lib, ik, m, q_k)
        if up is None:
            return f"no approach {LIFT} m above the keyframe of {a}"
        still = [o for o in lib.objects if o not in holding.values()]
        carrying = holding.get(m)
        grip = None if carrying is None else (carrying, rel_T(values[Var("x", carrying, k)], lib.upright(m)))
        resting = {o: drawers.world(lib, o, values, k) for o in still}
        transits.append(Transit(len(phases), len(path) - 1, m, grip, resting))
        for row in [*up[::-1], q_k]:  # to the approach, then down the lift's rows onto the keyframe
            cur[m] = row
            path.append(full())
        keyframes.append(full())
        low[m] = True
        if a.name == Kind.PICK:
            phases.append(Phase(np.array(path), None, grasp=obj, arm=m, carried=carried, action=k))
            holding[m] = obj
        else:  # place, stack; a drop's object falls into the drawer
            phases.append(Phase(np.array(path), obj, release=obj, fall=a.name == Kind.DROP, arm=m, carried=carried,
                                action=k))
            holding.pop(m, None)
        drawers.after(lib, a)
    path = [full()]
    why = lift_low(path, None, "the last action", len(actions))
    if why is not None:
        return why
    carried = tuple(holding.items())
    phases.append(Phase(np.array(path), None, carried=carried))
    return tuple(phases), np.array(keyframes).reshape(len(keyframes), -1), tuple(transits)
