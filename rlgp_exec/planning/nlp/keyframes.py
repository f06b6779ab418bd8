"""Level 2 of LGP: one NLP over every mode-switch configuration of a candidate action sequence.

For actions a_1..a_K the variables are the keyframes z_1..z_K (base and arm at each switch). Each
``pick`` puts the tool at a top grasp of its object (position, approach straight down, fingers across
two faces); the grasp is remembered as T_tool_obj = T_tool(z_pick)^-1 T_obj (the kinematic switch:
the object does not move relative to the hand while held). Each ``place`` then puts the object,
T_tool(z_place) T_tool_obj, upright on its target: resting on the surface, inside the region. Every
keyframe keeps the arm spheres clear of the fixtures and of the objects still where the scene put
them, and the base clear of fixture footprints. The objective is the weighted squared distance
between consecutive keyframes (from the start), a proxy for motion cost.

A flat object's grasp or release puts the tool point nearer the surface under it than the arm's tool
sphere can be (a 5 cm cube: 25 mm, the PR2's sphere and margin 50 mm): against the fixtures and objects
that close, the fingers' own geometry stands for the tool sphere (``_hand_fixtures``, ``_hand_objects``;
``pinned_conflict`` alike). An object set down at an earlier keyframe is grasped again where that
keyframe put it (its pose variable), and an object set down keeps clear of the objects standing beside
its target (``_standing_beside``: it would land on or in them); one set down on a fixture's top at large
keeps off the regions marked on it.

Drawers (``nlp.drawer_factors``): ``take_knob`` puts the hand on the knob where the drawer is now;
``open_drawer``/``close_drawer`` are the articulated constraint (the hand, holding the knob, moves with
the drawer's prismatic joint by the change of opening; the knob is let go at the end); ``drop`` holds
the object upright over the pulled-out part of an open drawer, a little below or above its rim. The
drawer's boxes, at each keyframe's opening, are obstacles (but not the one whose knob the hand is on).

Each start's initial guess comes from ``nlp.keyframe_seeds``.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import casadi as ca
import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.ipopt import LEAN
from rlgp_exec.planning import budget
from rlgp_exec.planning.actions import DRAWER_ACTIONS, GEOMETRIC_ACTIONS, MOVES_OBJECT, RELEASES, SETS_DOWN, Kind
from rlgp_exec.planning.detour import rect_distance
from rlgp_exec.planning.drawers import drawer_views
from rlgp_exec.planning.margins import BASE_MARGIN, FEAS_TOL, PLACE_LIFT
from rlgp_exec.planning.nlp.action import Action, target_surface
from rlgp_exec.planning.nlp.drawer_factors import drop_above, follow_prismatic, knob_grasp
from rlgp_exec.planning.nlp.factors import (
    GRASP_DEPTH,
    RobotSymbols,
    Rows,
    approach_bounds,
    box_clear,
    closing_bounds,
    footprint_clear,
    grasp_point,
    grasp_top,
    grasp_top_round,
    inside_rectangle,
)
from rlgp_exec.planning.nlp.hand import points_clear, points_clear_moving, self_rows_function, upper_arm_spheres
from rlgp_exec.planning.nlp.keyframe_seeds import attempt_guess
from rlgp_exec.planning.nlp.pick_fingers import finger_set, pick_room, too_close
from rlgp_exec.planning.nlp.poses import object_poses_after
from rlgp_exec.reach.checker import CLEARANCE
from rlgp_exec.reach.ik import ReachIK, arm_spheres, box_sdf
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import PANEL, Box, fixture_boxes, object_box, region_box

__all__ = ["ACTIONS", "DRAWER_ACTIONS", "Action", "KeyframeResult", "solve_keyframes"]

log = logging.getLogger(__name__)
W_BASE = 3.0  # base motion weighs more than arm motion in the objective
W_TILT = 20.0  # a tilted grasp costs like ~2.5 m of base motion at full tilt: only when it must
ATTEMPTS = 8  # initial guesses tried before a keyframe problem counts as infeasible
# IPOPT's successive restoration iterations before it gives a start up: a start stuck in restoration
# rarely recovers, and successful solves leave it far sooner
MAX_RESTO_ITER = 100
HAND_MARGIN = 0.008  # [m] the open fingers' spheres keep this from fixtures and standing objects
ARM_MARGIN = 0.015  # [m] the arm spheres keep this much more from the boxes (room for the guided paths)
PLACE_GAP = 0.02  # [m] between objects placed on one target (footprint circles)
BESIDE_GAP = 0.01  # [m] between a set-down object's footprint circle and a standing object's box
REACH_SLACK = 0.05  # [m] boxes this much beyond what the fingers can reach from an action's site keep their rows too
FINGER_REACH = 0.15  # [m] past an action's site (and the object's own extent) the fingers may reach sideways
DROP_GAP = 0.05  # [m] between objects dropped into one drawer: a fall lands a few cm off the release point
DROP_LOW, DROP_HIGH = -0.06, 0.02  # [m] a dropped object's bottom between these heights from the drawer's rim
CURVATURE_FREE = ("clearance", "base footprint")  # rows (by label ending) whose curvature IPOPT's Hessian leaves out
ACTIONS = GEOMETRIC_ACTIONS
#: each kind's rows, as the labels name them
KIND: dict[str, str] = {Kind.PICK: "grasp", Kind.PLACE: "placement", Kind.TAKE_KNOB: "knob grasp",
                        Kind.OPEN_DRAWER: "knob", Kind.CLOSE_DRAWER: "knob", Kind.DROP: "drop", Kind.STACK: "stacking"}
STACK_SLACK = 0.01  # [m] a stacked object's centre may stray this far past the support's footprint less its own


@dataclass(frozen=True)
class KeyframeResult:
    ok: bool
    keyframes: FloatArray  # (K, nq)
    object_poses: tuple[dict[str, FloatArray], ...]  # after each action: T_world_obj of every object
    openings: tuple[dict[str, float], ...]  # at each keyframe: every drawer's opening [m]
    cost: float
    violation: float
    solve_ms: float
    reason: str
    doomed: int = 0  # on failure: the first ``doomed`` actions fail whatever follows (0: not known)


def _rigid_inv(T: ca.SX) -> ca.SX:
    R, p = T[:3, :3], T[:3, 3]
    out = ca.SX.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ p
    return out


def pinned_conflict(
    model: RobotModel, scene: Scene, actions: list[Action], manipulator: str | None = None,
    hand: Sequence[tuple[FloatArray, float]] = (), mesh_hand: Sequence[tuple[FloatArray, float]] = (),
    max_tilt: float = 0.0, palm_hand: Sequence[tuple[FloatArray, float]] = (),
    tip_points: Sequence[tuple[FloatArray, float]] = (),
) -> str | None:
    """The reason no keyframe NLP of ``actions`` can be feasible, found without building it: a pick pins
    the tool point (its grasp row: ``grasp_point``, GRASP_DEPTH below the object's top centre), so the tool sphere's
    clearance rows against the fixtures (ARM_MARGIN) are numbers there, and so are the open fingers' rows
    against the objects standing where the scene put them for each closing the grasp rows allow
    (``nlp.pick_fingers.pick_room``: ``hand`` with HAND_MARGIN, ``mesh_hand`` with CLEARANCE; without
    finger spheres, the tool sphere with HAND_MARGIN; ``palm_hand``, the palm's own boxes, with HAND_MARGIN).
    A fixture row below its bound by more than FEAS_TOL,
    or every closing short of room by more, fails every start (pick_place_pr2 seed 3: a block 4 cm from
    another, 16 starts of ~1 s at both tilts, each ending 1.99 mm short). With ``max_tilt`` > 0 the leaning
    closings are a grid (``pick_fingers.TILT_STEPS``). The fixtures the tool sphere cannot clear at the grasp
    point (the surface under a flat object) are the fingers' instead: ``tip_points`` (the fingertips' leading
    vertices, ``nlp.hand.mesh_finger_tips``) with CLEARANCE when given. None if no pick is pinned into an
    obstacle."""
    manip = model.manipulator(manipulator)
    r_tool = [r for f, r in arm_spheres(model, manip.name) if f == manip.tool_frame]
    fingers = [f for f in (finger_set(hand, HAND_MARGIN), finger_set(mesh_hand, CLEARANCE)) if len(f.radii)]
    if fingers and palm_hand:  # the hand's own body round the pick, as the NLP's rows have it
        fingers.append(finger_set(palm_hand, HAND_MARGIN))
    if not r_tool and not fingers:
        return None
    fixture_bx = [b for fx in scene.fixtures for b in fixture_boxes(fx)]
    objs = {o.name: o for o in scene.objects}
    moved = {scene.start.held} if scene.start.held is not None else set()
    for a in actions:
        # an object moved earlier in the sequence is picked where that keyframe put it: not pinned yet
        if a.name == Kind.PICK and a.obj in objs and a.obj not in moved:
            o = objs[a.obj]
            top = grasp_point(o.T, o.size)
            still = [object_box(objs[m]) for m in objs if m not in moved and m != a.obj]
            # the fixtures the pinned tool sphere cannot clear (the surface under a flat object) are the
            # fingers' to clear, as the NLP's rows have it (``_hand_fixtures``)
            near = too_close(top, fixture_bx, r_tool[0] + ARM_MARGIN - FEAS_TOL) if r_tool and fingers else []
            tool_rows = [(b, ARM_MARGIN) for b in fixture_bx if all(b is not n for n in near)]
            tool_rows += [] if fingers else [(b, HAND_MARGIN) for b in still]
            for b, margin in tool_rows if r_tool else []:
                local = np.linalg.solve(b.T, np.r_[top, 1.0])[:3]
                d = float(box_sdf(ca.DM(local), np.asarray(b.size) / 2))
                if d < r_tool[0] + margin - FEAS_TOL:
                    return (f"{a}: its grasp point is {d * 1e3:.1f} mm from {b.name} (the tool sphere needs "
                            f"{(r_tool[0] + margin) * 1e3:.1f} mm)")
            if fingers:
                round_sides = o.shape == "cylinder"
                room, blockers = pick_room(o.T, top, np.asarray(manip.approach, float),
                                           np.asarray(manip.closing, float), fingers, still,
                                           0.0 if round_sides else max_tilt, FEAS_TOL, round_sides, near,
                                           [finger_set(tip_points, CLEARANCE)] if tip_points else [])
                if room is None:
                    sides = "from any side" if round_sides else "across either pair of faces"
                    return (f"{a}: the open fingers hit {' and '.join(blockers)} at every closing of its grasp "
                            f"({sides}, tilt <= {max_tilt:.1f} rad)")
        if a.name in MOVES_OBJECT:
            moved.add(a.obj)
    return None


def _tool_point(
    scene: Scene, a: Action, objs: dict, poses: dict[str, FloatArray], placed: dict, tops: dict[str, FloatArray],
) -> FloatArray | None:
    """Where action ``a`` puts the tool point (world (3,) [m]), GRASP_DEPTH below the top of the object it
    picks or sets down: exactly for a pick (the object where it stands, or as an earlier keyframe targeted
    it), over the target's centre for a place or stack; None for the other actions."""
    if a.name not in (Kind.PICK, Kind.PLACE, Kind.STACK):
        return None
    o = objs[a.obj]
    down = np.array([0.0, 0.0, min(GRASP_DEPTH, o.size[2] / 2)])
    if a.name == Kind.PICK:
        top = tops[a.obj] if a.obj in placed else poses[a.obj][:3, 3] + np.array([0.0, 0.0, o.size[2] / 2])
        return top - down
    if a.target is None:
        return None
    if a.target in objs:  # onto another object's top, where it stands or was set down
        b = objs[a.target]
        top_b = tops.get(a.target, poses[a.target][:3, 3] + np.array([0.0, 0.0, b.size[2] / 2]))
        return top_b + np.array([0.0, 0.0, PLACE_LIFT + o.size[2]]) - down
    T, _, z = target_surface(scene, a.target)
    return np.array([T[0, 3], T[1, 3], z + PLACE_LIFT + o.size[2]]) - down


def _standing_beside(
    still_bx: list[Box], tool_point: FloatArray, size: tuple[float, float, float], site: FloatArray, reach: float,
    support: str,
) -> list[Box]:
    """The standing objects' boxes a put-down object could land on or in (not its ``support``): those whose
    height overlaps the object's, set down with its tool point at ``tool_point`` (3,) (world [m]), and whose
    centre is within ``reach`` [m] plus their own half diagonal of the target's ``site`` (x y (2,))."""
    top = float(tool_point[2]) + min(GRASP_DEPTH, size[2] / 2)
    bottom = top - size[2]
    out = []
    for b in still_bx:
        if b.name == support:
            continue
        half_z = float(np.abs(b.T[2, :3]) @ np.asarray(b.size)) / 2
        if b.T[2, 3] + half_z <= bottom + PLACE_LIFT or b.T[2, 3] - half_z >= top:
            continue
        if np.linalg.norm(b.T[:2, 3] - site) < reach + float(np.hypot(b.size[0], b.size[1])) / 2:
            out.append(b)
    return out


def _tool_need(rs: RobotSymbols, margin: float) -> float | None:
    """The clearance [m] the tool sphere keeps (its radius + ``margin``), None if the arm has no tool sphere."""
    r_tool = [r for f, r in rs.spheres if f == rs.manip.tool_frame]
    return r_tool[0] + margin if r_tool else None


def _hand_fixtures(
    rs: RobotSymbols, fixture_bx: list[Box], tool_point: FloatArray, fingers: Sequence[tuple[FloatArray, float]],
    rows: Rows,
) -> list[Box]:
    """Rows against the fixtures the tool sphere cannot clear at a grasp or release whose tool point is
    ``tool_point`` (3,) (world [m]; the surface under a flat object): the fingers' spheres (tool frame,
    CLEARANCE: the keyframe check's) and the arm's other spheres (ARM_MARGIN) instead of the tool sphere.
    Returns the other fixture boxes, whose rows keep the tool sphere."""
    need = _tool_need(rs, ARM_MARGIN)
    near = too_close(tool_point, fixture_bx, need) if need is not None and fingers else []
    if near:
        box_clear(rs, near, rows, margin=ARM_MARGIN, skip=(rs.manip.tool_frame,))
        points_clear(rs.T_tool, list(fingers), near, rows, margin=CLEARANCE)
    return [b for b in fixture_bx if all(b is not n for n in near)]


def _hand_objects(rs: RobotSymbols, still_bx: list[Box], tool_point: FloatArray, rows: Rows) -> list[Box]:
    """``_hand_fixtures`` for the standing objects at a release (a block stacked onto a flat one): the arm's
    other spheres keep ARM_MARGIN from those the tool sphere cannot clear, the finger rows near the site
    (``_build``) stand for the tool sphere. Returns the other objects' boxes."""
    need = _tool_need(rs, ARM_MARGIN)
    near = too_close(tool_point, still_bx, need) if need is not None else []
    if near:
        box_clear(rs, near, rows, margin=ARM_MARGIN, skip=(rs.manip.tool_frame,))
    return [b for b in still_bx if all(b is not n for n in near)]


def _site_disc(
    scene: Scene, a: Action, poses: dict[str, FloatArray], drawers: dict, openings: dict[str, float]
) -> tuple[FloatArray, float]:
    """Where action a's hand goes, as a disc in the world plane: (centre x y (2,), radius [m]); the
    object's footprint for a pick (or a stack onto it), the target rectangle for a place or drop, the knob
    for a drawer."""
    if a.name == Kind.PICK:
        return poses[a.obj][:2, 3], float(np.hypot(*scene.object(a.obj).size[:2])) / 2
    if a.name in DRAWER_ACTIONS or a.target is None:
        return drawers[a.obj].T_world_knob(openings[a.obj])[:2, 3], 0.0
    if a.name == Kind.DROP:
        T, half = drawers[a.target].drop_rect(max(openings[a.target], drawers[a.target].travel), 0.0)
        return T[:2, 3], float(np.hypot(*half))
    if a.name == Kind.STACK and a.target in poses:  # onto a movable: its footprint (where the scene put it)
        return poses[a.target][:2, 3], float(np.hypot(*scene.object(a.target).size[:2])) / 2
    T, half, _ = target_surface(scene, a.target)
    return T[:2, 3], float(np.hypot(*half))


def finger_reach(spheres: Sequence[tuple[FloatArray, float]]) -> float:
    """How far [m] spheres (tool frame centre (3,), radius) reach from the tool point, in any orientation."""
    return max((float(np.linalg.norm(c)) + r for c, r in spheres), default=0.0)


def _near_site(boxes: list[Box], site: FloatArray, reach: float) -> list[Box]:
    """The boxes whose footprint (yaw-only boxes) comes within ``reach`` [m] of ``site`` (x y (2,), world)."""
    return [b for b in boxes if rect_distance(site, b.T, np.asarray(b.size)) < reach]


def _obstacles(a: Action, before: dict[str, FloatArray], after: dict[str, FloatArray]) -> dict[str, FloatArray]:
    """The objects that are obstacles at action a's keyframe (T_world_obj): all but the one being
    grasped, set down or dropped (in or round the open hand), where they stand before the action; for
    open/close_drawer, whose keyframe is the end of the motion, where they stand after it (what lies in
    the drawer moved with it)."""
    if a.name in (Kind.OPEN_DRAWER, Kind.CLOSE_DRAWER):
        return dict(after)
    return {m: T for m, T in before.items() if not (a.name in MOVES_OBJECT and m == a.obj)}


def _objects_clear(
    rs: RobotSymbols, boxes: list[Box], rows: Rows, tool_margin: float, skip: tuple[str, ...] = ()
) -> None:
    """The arm spheres clear of the standing objects' boxes: ARM_MARGIN [m] beyond their radii, the
    tool's sphere ``tool_margin`` [m]. A pick pins the tool point inside the grasped object: with
    ARM_MARGIN its sphere (radius 0.035 m on the PR2) would need 5 cm from a neighbour's face, which no
    grasp of a 5 cm block 7.5 cm from another has (pick_place_pr2 seed 3 missed it by 0.3 mm), while
    the real fingers (meshes, checked in PyBullet at the keyframe and in the replay) fit between them;
    a pick passes HAND_MARGIN, the open hand's margin, or ``skip`` the tool (and palm) frames where finger
    (and palm box) spheres of their own stand for the hand round the tool point (a block 1 cm from its
    neighbours: the fingers close across its free sides, which the tool sphere cannot tell from the others)."""
    box_clear(rs, boxes, rows, margin=ARM_MARGIN, tool_margin=tool_margin, skip=skip)


def _pose_variable(name: str, T: ca.SX, rows: Rows) -> tuple[ca.SX, ca.SX]:
    """A variable P (12,) for the pose ``T`` (4, 4), an expression of keyframes (where a place releases
    its object: the hand there times the grasp, which reads the pick), with the 12 rows P = T[:3, :4]
    (column-major): returns P and T_P (4, 4) built from it. Rows that read T_P (the place's own, and
    later keyframes' fingers kept off the placed object, objects set down apart) read P alone, not the
    keyframes behind it, and the Lagrangian's Hessian keeps its block structure. pick_place_pr2, 6
    actions: rows reading 3 or 4 keyframes made the Hessian 60 x 60 dense; IPOPT's Hessian had 407k
    instructions and nlpsol took 1.2 s, against 264k and 0.4 s with the pose variables (a grasp
    variable as well, T_tool_obj read by the place, changed neither)."""
    P = ca.SX.sym(name, 12)
    rows.add_all(P - ca.vec(T[:3, :4]), [0.0] * 12, 0.0)
    T_P = ca.SX.eye(4)
    T_P[:3, :4] = ca.reshape(P, 3, 4)
    return P, T_P


def _constraints(rows: Rows) -> ca.SX:
    """The rows' g as one column, not merged by ``ca.cse``: with the curvature-free rows (``_hess_lag``)
    the merge costs more to build than it saves in evaluation."""
    return ca.vertcat(*rows.g) if rows.g else ca.SX(0, 1)


def _jacobian(g: ca.SX, x: ca.SX, n: int) -> ca.SX:
    """dg/dx, the rows differentiated in groups by how many variables they read (at most ``n``, one
    keyframe's; at most 2 n; more: the rows that also read another keyframe or a pose variable). CasADi's
    forward sweeps colour the columns of all the rows at once, as many as the widest row reads (32 on
    pick_place_pr2, for 309 of its 393 rows that read at most 10): grouped, the narrow rows take 10, and
    the entries are the same."""
    if g.numel() == 0:
        return ca.SX(0, x.numel())
    width = np.diff(ca.jacobian_sparsity(g, x).T.colind())  # per row: the variables it reads
    rows = ca.vertsplit(g)
    groups = [np.flatnonzero(width <= n), np.flatnonzero((width > n) & (width <= 2 * n)), np.flatnonzero(width > 2 * n)]
    groups = [grp for grp in groups if grp.size]
    stacked = ca.vertcat(*(ca.jacobian(ca.vertcat(*(rows[i] for i in grp)), x) for grp in groups))
    order = np.argsort(np.concatenate(groups), kind="stable")  # stacked row of each row of g
    return stacked[order.tolist(), :]


def _hess_lag(x: ca.SX, p: ca.SX, f: ca.SX, g: ca.SX, labels: list[str]) -> ca.Function:
    """IPOPT's Hessian of the Lagrangian, (x, p, lam_f, lam_g) -> its upper triangle, with the curvature
    of the objective and of the task rows (grasps, placements, pose variables, drawers) but not of
    the clearance and base footprint rows (``CURVATURE_FREE``): those are most of the rows, and
    their second derivatives most of the Hessian's cost, as sequential convexification leaves them
    out too. The rows themselves and their Jacobian stay exact, so a solution is the same KKT point.
    Proving a start infeasible may take more iterations."""
    curved = [i for i, label in enumerate(labels) if not label.endswith(CURVATURE_FREE)]
    lam_f, lam_g = ca.SX.sym("lam_f"), ca.SX.sym("lam_g", g.numel())
    lagrangian = lam_f * f + (ca.dot(lam_g[curved], g[curved]) if curved else 0.0)
    return ca.Function("hess_lag", [x, p, lam_f, lam_g], [ca.triu(ca.hessian(lagrangian, x)[0])])


@dataclass(frozen=True)
class _Problem:
    """A built keyframe NLP for one action sequence: the solver and what its solutions are read with.
    The grasps' tilt bounds are not in ``lbg``/``ubg``: the approach rows from each of ``tilt_rows`` get
    ``approach_rows``' bounds for each solve's max_tilt."""

    n: int
    K: int
    solver: ca.Function
    f_motion: ca.Function
    labels: list[str]
    targets: list[FloatArray | None]
    opening_at: list[dict[str, float]]
    footprints_at: list[list[tuple[FloatArray, FloatArray]]]
    poses: dict[str, FloatArray]
    openings0: dict[str, float]
    held_grasp: FloatArray | None  # T_tool_obj of the start's held object
    sizes: dict[str, tuple[float, float, float]]
    lbx: FloatArray
    ubx: FloatArray
    lbg: FloatArray
    ubg: FloatArray
    tilt_rows: list[int]
    row_keyframe: FloatArray  # (rows,) the keyframe whose action each row belongs to
    couples: tuple[tuple[int, ...], ...]  # per keyframe: the other keyframes its rows also read
    aux0: ca.Function  # vec(Z) (n K,) -> the pose variables (12 each) that agree with those keyframes
    aux_reads: tuple[tuple[int, ...], ...]  # per pose variable: the keyframes its pose is an expression of


def _build(
    model: RobotModel,
    scene: Scene,
    q_start: FloatArray,
    actions: list[Action],
    manipulator: str | None,
    ik: ReachIK,
    hand: Sequence[tuple[FloatArray, float]],
    self_spheres: Sequence[tuple[str, FloatArray, float]],
    body: Sequence[tuple[str, Box]],
    lift_room: float,
    objs: dict,
    drawers: dict,
    mesh_hand: Sequence[tuple[FloatArray, float]] = (),
    inner: Sequence[tuple[str, Box]] = (),
    palm_hand: Sequence[tuple[FloatArray, float]] = (),
    tip_points: Sequence[tuple[FloatArray, float]] = (),
) -> _Problem:
    """The keyframe NLP of ``actions`` (``solve_keyframes`` documents the arguments), built once."""
    n, K = len(ik.idx), len(actions)
    Z = ca.SX.sym("z", n, K)
    self_rows = self_rows_function(model, self_spheres, body)
    inner_rows = self_rows_function(model, upper_arm_spheres(self_spheres), inner)
    tilt_rows: list[int] = []
    rows = Rows.empty()
    hand_reach = finger_reach(hand)
    fixture_rects = [(fx.T, np.asarray(fx.size)) for fx in scene.fixtures]
    fixture_bx = [b for fx in scene.fixtures for b in fixture_boxes(fx)]
    lift_name = model.joint_names[int(ik.idx[3])] if len(ik.idx) > 3 else ""
    poses: dict[str, FloatArray] = {name: o.T.copy() for name, o in objs.items()}
    openings = {c: scene.start.opening(c) for c in drawers}
    openings0 = dict(openings)
    opening_at: list[dict[str, float]] = []  # the drawers' openings at each keyframe
    footprints_at: list[list[tuple[FloatArray, FloatArray]]] = []  # (T, size) the base must avoid, per keyframe
    moved: set[str] = set()
    set_down: dict[str, list[tuple[str, ca.SX, float]]] = {}  # target -> (object, its x y, radius [m])
    # object -> (T_world_obj where an earlier keyframe put it (an expression), the target's centre x y and
    # half diagonal [m])
    placed: dict[str, tuple[ca.SX, FloatArray, float]] = {}
    placed_by: dict[str, tuple[int, ...]] = {}  # object -> the keyframes its placed pose reads (place, pick)
    tops: dict[str, FloatArray] = {}  # object set down at a keyframe -> its top centre as targeted (world [m])
    held: str | None = scene.start.held  # the start's grasp: T_tool_obj is fixed, the kinematic switch
    knob: str | None = None
    grasp: ca.SX | ca.DM | None = None if held is None else ca.DM(scene.start.T_tool_obj)
    held_T0 = None if held is None else scene.start.T_tool_obj
    if held is not None:
        moved.add(held)  # rides in the hand: no obstacle where it stands
    targets: list[FloatArray | None] = []  # None: the keyframe follows from the previous one
    labels: list[str] = []  # one per constraint row, for the failure reason
    tilts: list[ca.SX] = []  # 1 + a_z of each grasp: a vertical hand carries objects most safely
    row_keyframe: list[int] = []
    couples: list[tuple[int, ...]] = []
    picked_at: int | None = None  # the keyframe of the grasp held now (None: the start's, or none)
    regrasp = False  # the grasp held now is of an object an earlier keyframe set down (reads its pose variable)
    aux: list[tuple[ca.SX, ca.SX, tuple[int, ...]]] = []  # pose variables: (P, its expression, keyframes read)
    for k, a in enumerate(actions):
        budget.check()  # a keyframe's rows grow with the objects and fixtures round it
        row_keyframe += [k - 1] * (len(rows.g) - len(row_keyframe))
        couples.append(())
        rs = RobotSymbols(model, q_start, manipulator, Z[:, k], frames=(*self_rows.frames, *inner_rows.frames))
        if a.name in (Kind.OPEN_DRAWER, Kind.CLOSE_DRAWER):
            if knob != a.obj:
                raise RlgpError(f"keyframe NLP: {a} without holding the knob of {a.obj} (holding {knob})")
            new = drawers[a.obj].travel if a.name == Kind.OPEN_DRAWER else 0.0
            n0 = len(rows.g)
            follow_prismatic(Z[:, k], Z[:, k - 1], drawers[a.obj].axis_world, new - openings[a.obj], rows)
            couples[k] = (k - 1,)
            labels += [f"{a} follows the drawer"] * (len(rows.g) - n0)
            openings[a.obj], knob = new, None
            targets.append(None)
        at_knob = a.name in DRAWER_ACTIONS
        still = [object_box(objs[m]) for m in objs if m not in moved and m != a.obj]
        drawer_bx = [b for c, v in drawers.items() if not (at_knob and c == a.obj) for b in v.boxes(openings[c])]
        n0 = len(rows.g)
        still_bx = [replace(b, T=poses[b.name]) for b in still]
        own_hand = a.name == Kind.PICK and bool(hand or mesh_hand)
        tool_point = _tool_point(scene, a, objs, poses, placed, tops) if hand or mesh_hand else None
        tool_fixtures, tool_objects = fixture_bx, still_bx
        if tool_point is not None:  # the fingers, not the tool sphere, by the surface under a flat object
            tool_fixtures = _hand_fixtures(rs, fixture_bx, tool_point, list(tip_points) or [*hand, *mesh_hand], rows)
            if not own_hand:  # a release onto a flat object: the fingers' rows below keep off it
                tool_objects = _hand_objects(rs, still_bx, tool_point, rows)
        box_clear(rs, tool_fixtures + drawer_bx, rows, margin=ARM_MARGIN)
        skip = ((rs.manip.tool_frame,) + ((rs.manip.palm_frame,) if palm_hand else ())) if own_hand else ()
        _objects_clear(rs, tool_objects, rows, HAND_MARGIN if a.name == Kind.PICK else ARM_MARGIN, skip)
        rows.add_all(self_rows.rows(rs), self_rows.lower, ca.inf)
        rows.add_all(inner_rows.rows(rs), inner_rows.lower, ca.inf)
        site, r_site = _site_disc(scene, a, poses, drawers, openings)
        if a.name == Kind.STACK and a.target in placed:  # the support stands where an earlier keyframe put it
            site, r_site = placed[a.target][1], placed[a.target][2]
        if own_hand and palm_hand:
            points_clear(rs.T_tool, list(palm_hand), _near_site(still_bx, site, r_site + FINGER_REACH), rows,
                         margin=HAND_MARGIN)
        if hand:
            finger_bx = [b for c, v in drawers.items() for b in v.boxes(openings[c], knob=not (at_knob and c == a.obj))]
            # the open fingers keep the graph's clearance (and a little) from fixtures and standing objects:
            # the vertical approach from above then starts from a configuration the graph accepts. Only boxes the
            # fingers can reach from the action's site have rows (the others hold wherever the tool meets its site)
            r_tool = r_site  # where the tool can be: in the held object, whose centre is on the site
            if a.name in RELEASES:
                r_tool += float(np.linalg.norm(objs[a.obj].size)) / 2
            reach = r_tool + hand_reach + HAND_MARGIN + REACH_SLACK
            near_bx = _near_site(fixture_bx + still_bx, site, reach)
            points_clear(rs.T_tool, list(hand), near_bx, rows, margin=HAND_MARGIN)
            points_clear(rs.T_tool, list(hand), _near_site(finger_bx, site, reach), rows)  # knob grasps come close
        # mesh fingers (the PR2's) keep PyBullet's keyframe clearance from the standing objects, and every
        # finger from the objects set down at earlier keyframes (where those keyframes put them)
        if mesh_hand or placed:
            near = [b for b in still_bx
                    if np.linalg.norm(b.T[:2, 3] - site) < r_site + float(np.hypot(*b.size[:2])) / 2 + FINGER_REACH]
            points_clear(rs.T_tool, list(mesh_hand), near, rows, margin=CLEARANCE)
            for m, (T_m, xy_m, r_m) in placed.items():
                if m != a.obj and np.linalg.norm(xy_m - site) < r_site + r_m + FINGER_REACH:
                    couples[k] = (*couples[k], *placed_by[m])
                    points_clear_moving(rs.T_tool, [*hand, *mesh_hand], T_m, np.asarray(objs[m].size), rows,
                                        margin=CLEARANCE)
        labels += [f"{a} clearance"] * (len(rows.g) - n0)
        n0 = len(rows.g)
        open_rects = [(v.T_world_drawer(openings[c]), np.asarray(v.geometry.inner_box.size) + 2 * PANEL)
                      for c, v in drawers.items() if openings[c] > 0.0]
        footprint_clear(rs, fixture_rects + open_rects, rows, margin=BASE_MARGIN)
        footprints_at.append(fixture_rects + open_rects)
        labels += [f"{a} base footprint"] * (len(rows.g) - n0)
        opening_at.append(dict(openings))
        n0 = len(rows.g)
        if a.name == Kind.TAKE_KNOB:
            if held is not None or knob is not None:
                raise RlgpError(f"keyframe NLP: {a} while holding {held or knob}")
            T_knob = drawers[a.obj].T_world_knob(openings[a.obj])
            knob_grasp(rs, T_knob, rows)
            knob = a.obj
            targets.append(T_knob[:3, 3])
        elif a.name == Kind.PICK:
            if held is not None or knob is not None:
                raise RlgpError(f"keyframe NLP: {a} while holding {held or knob}")
            o = objs[a.obj]
            # an object an earlier keyframe set down is grasped where that keyframe put it (its pose variable)
            T_at: ca.SX | ca.DM = placed[a.obj][0] if a.obj in placed else ca.DM(poses[a.obj])
            regrasp = a.obj in placed
            if regrasp:
                couples[k] = (*couples[k], *placed_by[a.obj])
            if o.shape == "cylinder":  # a leaning hand touches a round side at two points only: the
                # object pivots about them as the fingers close (seen in physics: a cup tipped ~30 deg)
                tilts.append(grasp_top_round(rs, T_at, o.size, rows, max_tilt=0.0))
            else:  # flat faces: the pads stay vertical (closing axis horizontal), the box stays upright
                tilt_rows.append(len(rows.g) + 3)  # grasp_top's approach rows: their bounds set per solve
                tilts.append(grasp_top(rs, T_at, o.size, rows, max_tilt=0.0))
            grasp = _rigid_inv(rs.T_tool) @ T_at
            held, picked_at = a.obj, k
            placed.pop(a.obj, None)
            top_o = poses[a.obj][:3, 3] + np.array([0.0, 0.0, o.size[2] / 2])
            targets.append(tops.pop(a.obj) if a.obj in tops else top_o)
        elif a.name in RELEASES:
            if held != a.obj or grasp is None or a.target is None:
                raise RlgpError(f"keyframe NLP: {a} without holding {a.obj} (holding {held})")
            o = objs[a.obj]
            if picked_at is not None:  # and what that pick read (the pose it was set down at before)
                couples[k] = tuple(dict.fromkeys((*couples[k], picked_at, *couples[picked_at])))
            T_hand_obj = rs.T_tool @ grasp  # where the object is released: a variable, read by this place's
            P, T_obj = _pose_variable(f"T_{a.obj}_{k}", T_hand_obj, rows)  # rows and by later keyframes'
            expr = ca.vec(T_hand_obj[:3, :4])
            for P_prev, e_prev, _ in aux if regrasp else ():  # a grasp where a keyframe set it down reads
                expr = ca.substitute(expr, P_prev, e_prev)  # that pose variable: its expression instead
            aux.append((P, expr, (k, *couples[k])))
            labels += [f"{a} pose"] * (len(rows.g) - n0)
            n0 = len(rows.g)
            if a.name == Kind.STACK and a.target in objs:  # on the support's top face, wherever it stands now
                b = objs[a.target]
                T_below = placed[a.target][0] if a.target in placed else poses[a.target]
                half_b = (max((b.size[0] - max(o.size[:2])) / 2, 0.0) + STACK_SLACK,
                          max((b.size[1] - max(o.size[:2])) / 2, 0.0) + STACK_SLACK)
                inside_rectangle(T_obj[:2, 3], T_below, half_b, rows)
                rows.add(T_obj[2, 3] - (T_below[2, 3] + b.size[2] / 2 + o.size[2] / 2 + PLACE_LIFT), 0.0, 0.0)
                rows.add(T_obj[2, 2], 0.999, ca.inf)
                top = tops.get(a.target, poses[a.target][:3, 3] + np.array([0.0, 0.0, b.size[2] / 2]))
                targets.append(top + np.array([0.0, 0.0, o.size[2]]))
            elif a.name in SETS_DOWN:
                T_tgt, half, z_surf = target_surface(scene, a.target)
                margin = max(o.size[0], o.size[1]) / 2
                inside_rectangle(T_obj[:2, 3], T_tgt, (max(half[0] - margin, 0.0), max(half[1] - margin, 0.0)), rows)
                rows.add(T_obj[2, 3] - (z_surf + o.size[2] / 2 + PLACE_LIFT), 0.0, 0.0)
                rows.add(T_obj[2, 2], 0.999, ca.inf)  # upright (no bound at 1: ``factors.approach_rows``)
                targets.append(T_tgt[:3, 3] + np.array([0.0, 0.0, o.size[2]]))
            else:
                v = drawers[a.target]
                if openings[a.target] <= 0.0:
                    raise RlgpError(f"keyframe NLP: {a} into a closed drawer")
                T_rect, half = v.drop_rect(openings[a.target], max(o.size[0], o.size[1]) / 2)
                rim = v.rim_z(openings[a.target])
                drop_above(T_obj, T_rect, half, o.size, rim + DROP_LOW, rim + DROP_HIGH, rows)
                targets.append(T_rect[:3, 3] + np.array([0.0, 0.0, rim - T_rect[2, 3] + DROP_LOW + o.size[2]]))
            r_o = float(np.hypot(o.size[0], o.size[1])) / 2
            for _, xy, r_other in set_down.get(a.target, []):  # apart from what was set down there already
                gap = DROP_GAP if a.name == Kind.DROP else PLACE_GAP
                rows.add(ca.sumsqr(T_obj[:2, 3] - xy), (r_o + r_other + gap) ** 2, ca.inf)
            if a.name in SETS_DOWN and a.target not in objs and all(r.name != a.target for r in scene.regions):
                # set down on a fixture's top at large: off the regions marked on it (goals' places, pegs)
                for r in scene.regions:
                    if r.on == a.target:
                        rb = region_box(scene, r)
                        Tinv = np.linalg.inv(rb.T)
                        centre = ca.vertcat(T_obj[0, 3], T_obj[1, 3], float(rb.T[2, 3]))
                        local = ca.DM(Tinv[:3, :3]) @ centre + ca.DM(Tinv[:3, 3])
                        rows.add(box_sdf(local, np.asarray(rb.size) / 2), r_o + BESIDE_GAP, ca.inf)
            if a.name in SETS_DOWN and tool_point is not None:  # and from the objects standing on the target
                for b in _standing_beside(still_bx, tool_point, o.size, site, r_site + r_o, a.target):
                    # the object's footprint circle off the standing one's box (its own faces: a circle
                    # round both kept two 5 cm cubes 9 cm apart, more than a cleared goal region had)
                    Tinv = np.linalg.inv(b.T)
                    centre = ca.vertcat(T_obj[0, 3], T_obj[1, 3], float(b.T[2, 3]))
                    local = ca.DM(Tinv[:3, :3]) @ centre + ca.DM(Tinv[:3, 3])
                    rows.add(box_sdf(local, np.asarray(b.size) / 2), r_o + BESIDE_GAP, ca.inf)
            set_down.setdefault(a.target, []).append((a.obj, T_obj[:2, 3], r_o))
            if a.name in SETS_DOWN:  # a dropped object falls: where it lands is not this expression
                placed[a.obj] = (T_obj, site, r_site)
                tops[a.obj] = np.asarray(targets[-1], float)  # its top centre, as the seeds aim (world [m])
                placed_by[a.obj] = (k, *couples[k])
            moved.add(a.obj)
            held, grasp, picked_at = None, None, None
        if lift_room > 0.0 and a.name in MOVES_OBJECT and lift_name.endswith("lift_joint"):
            rows.add(Z[3, k], -ca.inf, float(ik.hi[3]) - lift_room)
        labels += [f"{a} {KIND[a.name]}"] * (len(rows.g) - n0)
    row_keyframe += [K - 1] * (len(rows.g) - len(row_keyframe))
    sizes = {m: o.size for m, o in objs.items()}
    z0 = ca.DM(ik.z_of(q_start))
    cost = ca.SX(0)
    prev: ca.SX | ca.DM = z0
    for k in range(K):
        d = Z[:, k] - prev
        cost += W_BASE * ca.sumsqr(d[:2]) + W_BASE * d[2] ** 2 + ca.sumsqr(d[3:])
        prev = Z[:, k]
    cost += W_TILT * sum(tilts, ca.SX(0))
    # Each start is one IPOPT solve of the motion cost from its initial guess: with the graph's seeds a
    # first solve for the feasible point nearest the guess no longer keeps a better basin, and costs time
    x = ca.vertcat(ca.vec(Z), *(P for P, _, _ in aux))
    pp = ca.SX.sym("p", 0)
    g_all = _constraints(rows)
    nlp = {"x": x, "p": pp, "f": cost, "g": g_all}
    opts: dict[str, Any] = {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 400,
                            "ipopt.tol": 1e-7, "ipopt.max_resto_iter": MAX_RESTO_ITER}
    opts["hess_lag"] = _hess_lag(x, pp, cost, g_all, labels)
    opts["jac_g"] = ca.Function("jac_g", [x, pp], [g_all, _jacobian(g_all, x, n)])
    solver = ca.nlpsol("keyframes", "ipopt", nlp, {**opts, **LEAN, **budget.ipopt_stop()})
    n_aux = 12 * len(aux)
    lo, hi = _keyframe_bounds(model, ik)
    lbx = np.r_[np.tile(lo, K), np.full(n_aux, -np.inf)]
    ubx = np.r_[np.tile(hi, K), np.full(n_aux, np.inf)]
    aux0 = ca.Function("aux0", [ca.vec(Z)], [ca.vertcat(*(e for _, e, _ in aux)) if aux else ca.DM(0, 1)])
    lbg, ubg = np.asarray(rows.lower, float), np.asarray(rows.upper, float)
    f_motion = ca.Function("f_motion", [ca.vec(Z)], [cost])
    return _Problem(
        n, K, solver, f_motion, labels, targets, opening_at, footprints_at, poses, openings0, held_T0, sizes,
        lbx, ubx, lbg, ubg, tilt_rows, np.asarray(row_keyframe, int), tuple(couples), aux0,
        tuple(r for _, _, r in aux),
    )


def _keyframe_bounds(model: RobotModel, ik: ReachIK) -> tuple[FloatArray, FloatArray]:
    """Bounds (n,) on a keyframe's z: IK's (the joint limits, the yaw free), each joint narrowed to the robot
    config's ``keyframe_limits`` (where its own hulls meet inside the URDF's limits)."""
    lo, hi = ik.lo.copy(), ik.hi.copy()
    for k, i in enumerate(ik.idx):
        narrow = model.config.keyframe_limits.get(model.joint_names[int(i)])
        if narrow is not None:
            lo[k], hi[k] = max(lo[k], narrow[0]), min(hi[k], narrow[1])
    return lo, hi


def _kept(prob: _Problem, zk: FloatArray, violated: FloatArray) -> dict[int, FloatArray]:
    """The keyframes (z (n,) each, from a failed start's solution ``zk`` (K, n)) a partial restart keeps: all
    but those with a ``violated`` row (bool (rows,)) and the keyframes those rows read (a place's pick, an
    open/close's knob grasp, the pick and place of an object a finger is kept off); none (a fresh start)
    when every keyframe with a target of its own would restart. The restarted ones get new initial guesses,
    and the kept ones hold the rest of the sequence where it was feasible (table_clearing_hsr: 5 fresh
    starts of ~2 s failed, each on a different one of its 8 keyframes)."""
    bad = set(prob.row_keyframe[violated].tolist())
    for k in list(bad):
        bad.update(prob.couples[k])
    own = [k for k in range(prob.K) if prob.targets[k] is not None]
    if all(k in bad for k in own):
        return {}
    return {k: zk[k] for k in own if k not in bad}


def solve_keyframes(
    model: RobotModel,
    scene: Scene,
    q_start: FloatArray,
    actions: list[Action],
    manipulator: str | None = None,
    seed: int = 0,
    in_collision: Callable[[FloatArray, dict[str, float], Action, dict[str, FloatArray]], bool] | None = None,
    max_tilt: float = 0.0,
    ik: ReachIK | None = None,
    hand: Sequence[tuple[FloatArray, float]] = (),
    self_spheres: Sequence[tuple[str, FloatArray, float]] = (),
    body: Sequence[tuple[str, Box]] = (),
    lift_room: float = 0.0,
    seeds: Callable[[FloatArray], list[FloatArray]] | None = None,
    cache: dict | None = None,
    mesh_hand: Sequence[tuple[FloatArray, float]] = (),
    inner: Sequence[tuple[str, Box]] = (),
    palm_hand: Sequence[tuple[FloatArray, float]] = (),
    tip_points: Sequence[tuple[FloatArray, float]] = (),
) -> KeyframeResult:
    """Solve the keyframe NLP (several initial guesses); ``in_collision(q, openings, action, objects)``
    (the full PyBullet check, self-collisions and mesh fingers included, which the NLP's shapes do not
    model; it gets the drawers' openings [m] at that keyframe, the action, and the objects that are
    obstacles there, T_world_obj where they stand) rejects a solution. ``max_tilt`` [rad]: how far from
    vertical a grasp's approach may lean. ``ik``: a ReachIK to reuse (its solver is built once).
    ``hand``: spheres on the open fingers (tool frame, ``nlp.hand.finger_spheres``), kept clear too;
    ``mesh_hand``: spheres on the fingers' mesh shapes (``nlp.hand.mesh_finger_spheres``), kept off the
    objects only; ``self_spheres``: spheres on the arm (``nlp.hand.arm_link_spheres``), kept off the ``body`` boxes
    (``nlp.hand.body_obstacles``), the upper arm's (``nlp.hand.upper_arm_spheres``) off the ``inner`` ones too
    (``nlp.hand.inner_obstacles``: the chest and the other arms' shoulders). ``palm_hand``: spheres on the palm's
    box shapes (``nlp.pick_fingers.palm_box_spheres``), which at a pick stand for the palm's arm sphere
    against the standing objects, as the fingers' spheres stand for the tool's. ``tip_points``: the
    fingertips' leading vertices (``nlp.hand.mesh_finger_tips``), which stand for the tool sphere against the
    surface under a flat object picked or set down (the finger spheres otherwise).
    ``lift_room`` [m]: at a pick, place or drop, an arm whose first joint is a lift keeps this much of
    its travel above it (the vertical leave is then one lift motion).
    ``seeds(x)``: initial guesses z (n,) for a keyframe whose hand goes to x (the reachability graph's
    nodes near x, nearest first); every other start uses them, the rest a random free base heading.
    The active budget (``planning.budget``) is checked before every start and by IPOPT's iterations:
    ``BudgetError`` once spent.
    After a PyBullet rejection the next attempt restarts only the rejected keyframes.
    ``cache``: a dict the caller keeps; the NLP built for this sequence is kept there and reused by the
    next call for the same sequence (another ``max_tilt``: only the tilt bounds differ)."""
    t0 = time.perf_counter()
    objs = {o.name: o for o in scene.objects}
    drawers = drawer_views(scene)
    for a in actions:
        if a.name not in ACTIONS:
            raise RlgpError(f"keyframe NLP: unknown action {a.name!r}; valid: {list(ACTIONS)}")
        if a.name in DRAWER_ACTIONS:
            if a.obj not in drawers:
                raise RlgpError(f"keyframe NLP: {a}: unknown drawer cabinet {a.obj!r}; valid: {sorted(drawers)}")
        elif a.obj not in objs:
            raise RlgpError(f"keyframe NLP: unknown object {a.obj!r}; valid: {sorted(objs)}")
        if a.name == Kind.DROP and a.target not in drawers:
            raise RlgpError(f"keyframe NLP: {a}: unknown drawer cabinet {a.target!r}; valid: {sorted(drawers)}")
    conflict = pinned_conflict(model, scene, actions, manipulator, hand, mesh_hand, max_tilt, palm_hand, tip_points)
    if conflict is not None:
        log.info("keyframes: infeasible before any start: %s", conflict)
        return KeyframeResult(False, np.zeros((0, model.nq)), (), (), math.inf, math.inf,
                              (time.perf_counter() - t0) * 1e3, f"infeasible grasp: {conflict}")
    ik = ik if ik is not None else ReachIK(model, scene, q_start, manipulator)
    key = (tuple(actions), manipulator, lift_room, id(ik))
    prob = cache.get(key) if cache is not None else None
    if prob is None:
        prob = _build(
            model, scene, q_start, actions, manipulator, ik, hand, self_spheres, body, lift_room, objs, drawers,
            mesh_hand, inner, palm_hand, tip_points,
        )
        if cache is not None:  # one sequence at a time: its tilts share the NLP
            cache.clear()
            cache[key] = prob
    n, K, solver, f_motion, labels, targets = prob.n, prob.K, prob.solver, prob.f_motion, prob.labels, prob.targets
    opening_at, footprints_at, poses = prob.opening_at, prob.footprints_at, prob.poses
    openings0, held_T0, sizes = prob.openings0, prob.held_grasp, prob.sizes
    lbx, ubx = prob.lbx, prob.ubx
    lbg, ubg = prob.lbg.copy(), prob.ubg.copy()
    for r in prob.tilt_rows:  # the approach rows of box grasps, for this tilt
        for i, (lower, upper) in enumerate(approach_bounds(max_tilt)):
            lbg[r + i], ubg[r + i] = lower, upper
        lbg[r + 3], ubg[r + 3] = closing_bounds(max_tilt)  # grasp_top's closing row, after the approach rows
    rng = np.random.default_rng(seed)
    z_start = ik.z_of(q_start)

    def solve(x0: FloatArray) -> tuple[dict, float, str]:
        """One IPOPT run: (result, largest constraint violation, the worst row's label)."""
        r = solver(x0=x0, lbx=lbx, ubx=ubx, lbg=lbg, ubg=ubg)
        budget.check()  # IPOPT stopped by ``budget.ipopt_stop``: this start's point is not a result
        st = solver.stats()
        log.debug("keyframes solve (%d rows): %s, %d iterations", lbg.size, st["return_status"], st["iter_count"])
        g = np.asarray(r["g"]).reshape(-1)
        over = np.maximum(lbg - g, g - ubg)
        v = float(np.max(np.r_[over, 0.0]))
        if v > FEAS_TOL and log.isEnabledFor(logging.DEBUG):
            worst5 = np.argsort(-over)[:5]
            log.debug("keyframes: worst rows %s",
                      [(labels[i], round(float(over[i]), 4)) for i in worst5 if over[i] > 0])
        return r, v, (labels[int(np.argmax(over))] if g.size else "")

    best = None
    keep: dict[int, FloatArray] = {}  # keyframes of a failed start to start from again (the others restart)
    tried: list[list[FloatArray]] = [[] for _ in range(K)]  # the initial guesses used at each keyframe
    for _attempt in range(ATTEMPTS):  # initial guesses: each keyframe from position IK at its target
        budget.check()
        init = attempt_guess(
            _attempt, model=model, ik=ik, actions=actions, targets=targets, footprints_at=footprints_at,
            opening_at=opening_at, drawers=drawers, poses=poses, objs=objs, z_start=z_start, seeds=seeds, rng=rng,
            keep=keep, tried=tried,
        )
        z_init = np.concatenate(init)
        x_init = np.r_[z_init, np.asarray(prob.aux0(z_init)).reshape(-1)]
        res, viol, worst = solve(x_init)
        restarted, keep = bool(keep), {}  # a partial restart is tried once, then a fresh start
        x_z = np.asarray(res["x"]).reshape(-1)[: n * K]  # the keyframes (the pose variables follow them)
        zk = x_z.reshape(K, n)
        if viol > FEAS_TOL and not restarted:  # restart the keyframes whose rows IPOPT could not satisfy
            g = np.asarray(res["g"]).reshape(-1)
            keep = _kept(prob, zk, np.maximum(lbg - g, g - ubg) > FEAS_TOL)
        if viol <= FEAS_TOL and in_collision is not None:
            qk = np.array([ik.q_of(np.clip(z, ik.lo, ik.hi)) for z in zk])
            after = object_poses_after(
                actions, qk, poses, opening_at, drawers, model, ik.tool, sizes, held_T0, openings0
            )
            obstacles = [_obstacles(actions[k], after[k - 1] if k else poses, after[k]) for k in range(K)]
            bad = [k for k in range(K) if in_collision(qk[k], opening_at[k], actions[k], obstacles[k])]
            if bad:  # feasible for the NLP, not for the robot: restart the rejected keyframes
                viol, worst = 1.0, f"{actions[bad[0]]} keyframe collides in PyBullet (self or world)"
                if not restarted:
                    keep = {k: zk[k] for k in range(K) if k not in bad and targets[k] is not None}
        status = solver.stats()["return_status"]
        log.debug("keyframes attempt %d: violation %.2e (%s) %s", _attempt, viol, worst, status)
        cand = (viol, float(f_motion(x_z)), x_z, worst)
        if best is None or (cand[0] < best[0] - 1e-9) or (cand[0] <= FEAS_TOL and cand[1] < best[1]):
            best = cand
        if viol <= FEAS_TOL:
            break
    viol, f, zflat, worst_row = best  # type: ignore[misc]
    zs = zflat.reshape(K, n)  # ca.vec is column-major: column k of Z is keyframe k
    # IPOPT may end a hair outside a bound (its bound relaxation, ~1e-8): keyframes are kept inside
    keyframes = np.array([ik.q_of(np.clip(z, ik.lo, ik.hi)) for z in zs])
    # object poses after each action, evaluated numerically
    out_poses = object_poses_after(
        actions, keyframes, poses, opening_at, drawers, model, ik.tool, sizes, held_T0, openings0
    )
    ok = viol <= FEAS_TOL
    return KeyframeResult(
        ok,
        keyframes,
        tuple(out_poses),
        tuple(opening_at),
        f,
        viol,
        (time.perf_counter() - t0) * 1e3,
        "ok" if ok else f"constraints violated by {viol:.2e} (worst: {worst_row})",
    )
