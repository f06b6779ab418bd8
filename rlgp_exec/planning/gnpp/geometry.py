"""The constraint functions h_b of the GNPP graph-NLP, one CasADi ``Function`` per kind and arguments.

Continuous variables (paper Sec. IV-A): an arm's configuration ``q``, and an object's pose ``x`` (4,) =
[x, y, z, yaw] [m, rad] relative to its parent: the world when it rests (on a fixture, a region or
another object), the holding arm's tool frame when held (then the object's z axis is the tool's
-approach axis, see ``tool_upright``).

``q`` is the arm's joints [rad] (the PR2: 7 per arm, base and torso fixed at the scene's start) or, when
the base moves (``FactorLib.mobile``: the paper's mobile manipulator of the Field scenario), ``[x, y, yaw]``
of the base in the world frame [m, rad] followed by the arm's joints (the HSR: lift [m] and four revolute
joints, the torso mimicking the lift; the PR2: 7 per arm, each arm's variable carrying the one base, kept
equal by ``SameBase``). Its shapes: the PR2's hand-placed spheres
(probed in PyBullet), else spheres from the model: the arm links' collision cylinders, the wrist, the
hand's and the open fingers' collision boxes, the base footprint circles (``nlp.hand``, ``nlp.factors``).

Each function is built once from the shared factors (``planning.nlp.factors``) and cached, so an NLP
of any subgraph is a composition of cached functions (their derivatives are cached too).
"""

from __future__ import annotations

import logging
import math
import re
from dataclasses import dataclass
from functools import cached_property

import casadi as ca
import numpy as np
import pybullet as p

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.capabilities import beyond_reach
from rlgp_exec.planning.gnpp.drawer_geometry import DROP_MARGIN, DrawerFactors
from rlgp_exec.planning.gnpp.held_pose import rel_pose as _rel_pose
from rlgp_exec.planning.gripper_limits import gripper_limits
from rlgp_exec.planning.margins import BASE_MARGIN, PLACE_LIFT, RELEASE_CLEARANCE
from rlgp_exec.planning.nlp.action import target_surface
from rlgp_exec.planning.nlp.factors import (
    GRASP_DEPTH,
    RobotSymbols,
    Rows,
    footprint_clear,
    points_apart,
    points_box_clear,
    upright_match,
    yaw_pose,
)
from rlgp_exec.planning.nlp.hand import arm_link_spheres, body_obstacles, link_box_spheres, self_clear
from rlgp_exec.reach import nominal_q
from rlgp_exec.reach.ik import box_sdf
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.robot.pybullet_body import PyBulletRobot
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Box, fixture_boxes

__all__ = [
    "FLOOR",
    "GRASP_DEPTH",
    "LIFT",
    "MAX_TILT",
    "PLACE_LIFT",
    "T_TOOL_UPRIGHT",
    "ArmShapes",
    "FactorFn",
    "FactorLib",
    "tool_upright",
]

log = logging.getLogger(__name__)

MAX_TILT = 0.9  # [rad] a grasping hand leans at most this far from vertical
WRIST_FLEX_MIN = -1.65  # [rad] (PR2) beyond it the open fingers touch the forearm at some rolls
PAN_CROSS_MAX = 0.1  # [rad] (PR2) shoulder pan towards the other arm's side at most
#: [rad] (PR2) shoulder pan outwards at most: further out, the upper arm's housing behind the shoulder meets the
#: torso at some upper-arm rolls. Probed in PyBullet (upper arm against torso_lift_link, the worst of 12-20 rolls
#: and 7 shoulder lifts): 3.8 mm clear at 1.1 rad, 0.6 mm at 1.2, 2 mm in at 1.3, either arm. Hanoi seed 0 once
#: ended a left-arm place at 1.295 rad, 1.9 mm into the torso, and the replay blocked the plan
PAN_OUT_MAX = 1.1
#: (PR2) the open fingertips' inner faces this far from the tool point along the closing axis [m]:
#: probed in the PyBullet model at the 0.5 rad finger opening every plan keeps
FINGER_INNER = 0.0375
FINGER_UP = 0.025  # [m] the second point of each open finger, this far above its tip (PR2 finger links)
STACK_TOL = 0.012  # [m] a stacked object's centre within this of its parent's axis (x and y)
FLOOR = 3.0  # [m] a mobile base's x and y stay within +-FLOOR of the world origin (as objects' poses do)
#: [m] a hand descends onto each keyframe and lifts off it along a vertical line this long (``motion``):
#: ``ColHO`` keeps that whole line of each hand sphere clear of the resting objects (the replay checks
#: it; a neighbour stacked higher than the keyframe met the fingers 4-6 cm up, obstacles_tower_pr2)
LIFT = 0.10


def tool_upright(approach: tuple[float, float, float], closing: tuple[float, float, float]) -> FloatArray:
    """R_tool_obj (3, 3) of an upright object held from above: its z axis the tool's -approach (the
    hand points down), its y axis the closing axis, x = y cross z."""
    z, y = -np.asarray(approach, float), np.asarray(closing, float)
    return np.column_stack([np.cross(y, z), y, z]) + 0.0  # no -0.0 entries


#: object frame in the PR2's tool frame for an upright object held from above (tool x = approach = down)
T_TOOL_UPRIGHT = tool_upright((1.0, 0.0, 0.0), (0.0, 1.0, 0.0))


@dataclass(frozen=True)
class ArmShapes:
    """An arm's collision spheres: ``fn`` maps its variable q to (centres (3, K) world [m], T_tool (4, 4));
    the index tuples say which spheres each collision factor uses."""

    fn: ca.Function
    radii: tuple[float, ...]
    fixture: tuple[int, ...]  # kept clear of the fixtures (ColFix)
    trunk: tuple[int, ...]  # kept clear of the PR2's torso box (ColFix)
    arm: tuple[int, ...]  # the arm up to the wrist, clear of resting objects (ColAO)
    hand: tuple[int, ...]  # the hand and open fingers, clear of resting objects (ColHO)
    other_arm: tuple[int, ...]  # against the other arm's same set (ColAA)


@dataclass(frozen=True)
class FactorFn:
    fn: ca.Function  # inputs: the variables in slot order; output: the rows g
    lower: FloatArray
    upper: FloatArray

    @cached_property
    def jac(self) -> ca.Function:
        """The rows' Jacobian in the inputs stacked in slot order: same inputs, output (rows, sum of the
        inputs' sizes) (built at first use, once per factor key: ``gnpp.assembly``)."""
        ins = [ca.SX.sym(f"v{k}", self.fn.sparsity_in(k)) for k in range(self.fn.n_in())]
        g = self.fn(*ins)
        return ca.Function(f"{self.fn.name()}_jac", ins, [ca.jacobian(g, ca.vertcat(*[ca.vec(v) for v in ins]))])


_W = ca.SX.sym("w", 4)
_YAW_POSE = ca.Function("yaw_pose", [_W], [yaw_pose(_W)])


class FactorLib(DrawerFactors):
    """The scene's factor functions and variable bounds (the base part of each arm's variable when it
    moves, see ``mobile``; else fixed at the start, as the torso always is); the drawers' from
    ``DrawerFactors``."""

    def __init__(self, model: RobotModel, scene: Scene, mobile: bool | None = None) -> None:
        self.model, self.scene = model, scene
        self.q_nominal = nominal_q(model, scene)
        self.arms = tuple(m.name for m in model.config.manipulators)
        #: the base belongs to every arm's configuration variable (the paper's mobile manipulator). One arm:
        #: always. Several arms on one base (the PR2): by default only when an object or a goal target lies
        #: beyond a sound bound of the arms' reach from the start base (``capabilities.beyond_reach``): the
        #: shared base couples the arms at every step (``SameBase``) and costs three variables each, which
        #: a task the start base serves does not need
        self.mobile = (len(self.arms) == 1 or bool(beyond_reach(scene))) if mobile is None else mobile
        #: the arm whose variable's base the move operators and ``EqualBase`` act on, and the others whose
        #: variable's base ``SameBase`` ties to it (none for one arm)
        self.base_arm = self.arms[0]
        self.riders: dict[str, str] = {m: self.base_arm for m in self.arms[1:]} if self.mobile else {}
        self.pr2 = model.config.name == "pr2"  # its hand-placed spheres and joint rules (probed in PyBullet)
        self._probe: tuple | None = None  # (finger spheres, hand spheres, body boxes) from PyBullet
        self.objects = {o.name: o for o in scene.objects}
        self._fns: dict[tuple, FactorFn] = {}
        self._arm: dict[str, ArmShapes] = {}
        self.fixture_boxes = [b for fx in scene.fixtures for b in fixture_boxes(fx)]
        self.body_boxes = self._body_boxes()

    def _body_boxes(self) -> list[Box]:
        """The robot's own trunk as boxes that its arms must clear (PR2: the torso, from its collision
        hull's bounding box [m]): in the base frame when the base moves (``mobile``), else in the world
        frame at the start base."""
        if self.model.config.name != "pr2":
            return []
        lift = self.q_nominal[self.model.index("torso_lift_joint")]
        T = np.eye(4)
        T[:3, 3] = [-0.15, 0.0, 0.69 + lift]  # base frame: x forward
        if not self.mobile:
            x, y, yaw = self.q_nominal[:3]
            T_world_base = np.eye(4)
            T_world_base[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
            T_world_base[:2, 3] = x, y
            T = T_world_base @ T
        return [Box("torso", (0.36, 0.5, 0.8), T, (0.5, 0.5, 0.5, 1.0))]

    # ----------------------------------------------------------------- variables
    def arm_index(self, arm: str) -> FloatArray:
        """The indices in the full q of the arm's variable (base first when ``mobile``)."""
        group = self.model.group(self.model.manipulator(arm).group)
        base = self.model.group("base") if self.mobile else ()
        return np.array([*base, *group], dtype=int)

    def dim(self, kind: str, owner: str) -> int:
        """The size of a variable: an arm's q (``arm_index``) or an object's pose (4)."""
        return len(self.arm_index(owner)) if kind == "q" else 4

    def var_bounds(self, kind: str, owner: str) -> tuple[FloatArray, FloatArray]:
        if kind == "q":
            idx = self.arm_index(owner)
            lo = np.maximum(self.model.limits.lower[idx], -2 * math.pi)
            hi = np.minimum(self.model.limits.upper[idx], 2 * math.pi)
            if self.mobile:  # base x, y on the floor
                lo[:2], hi[:2] = -FLOOR, FLOOR
            return lo, hi
        # an object's x is a world pose [x, y, z, yaw] or a held pose [d, s, psi, theta]: bounds for both
        return np.array([-3.0, -3.0, -4 * math.pi, -4 * math.pi]), np.array([3.0, 3.0, 4 * math.pi, 4 * math.pi])

    def home_q(self, arm: str) -> FloatArray:
        return self.q_nominal[self.arm_index(arm)].copy()

    def full_q(self, arms_q: dict[str, FloatArray]) -> FloatArray:
        q = self.q_nominal.copy()
        for arm, qa in arms_q.items():
            q[self.arm_index(arm)] = qa
        return q

    def call_context(self) -> dict[tuple[str, ...], str]:
        """Digests of the numbers behind this call's ``Ref`` (initial object poses) and ``RefQ`` (initial
        arm configurations) factors, for :meth:`SubgraphDB.bind` (0.1 mm / 0.1 mrad resolution)."""

        def digest(v: FloatArray) -> str:
            return ",".join(f"{x:.4f}" for x in np.asarray(v, float))

        ctx: dict[tuple[str, ...], str] = {("Ref", o): digest(self.start_pose(o)) for o in self.objects}
        ctx.update({("RefQ", m): digest(self.home_q(m)) for m in self.arms})
        return ctx

    def start_pose(self, obj: str) -> FloatArray:
        """The scene's pose of ``obj`` (4,): in the world, or in its drawer's frame (closed) if it starts in one."""
        o = self.objects[obj]
        if o.support.endswith(".drawer"):
            return self.in_drawer_frame(o.support.removesuffix(".drawer"), 0.0, o.T)
        return np.array([o.pose[0], o.pose[1], o.pose[2], o.pose[3]], float)

    def held_pose(self, obj: str) -> FloatArray:
        """The nominal held pose r = [d, s, psi, theta]: tool point GRASP_DEPTH below the top, centred,
        hand vertical."""
        h = self.objects[obj].size[2]
        return np.array([h / 2 - min(GRASP_DEPTH, h / 2), 0.0, 0.0, 0.0])

    def upright(self, arm: str) -> FloatArray:
        """R_tool_obj (3, 3) of an upright object held from above by ``arm`` (``tool_upright``)."""
        man = self.model.manipulator(arm)
        return tool_upright(man.approach, man.closing)

    def _probed(self) -> tuple:
        """(finger spheres, hand spheres (tool frame), body boxes (base_link frame)) read from the
        robot's collision shapes in PyBullet at the start configuration, hand open (not for the PR2)."""
        if self._probe is None:
            client = p.connect(p.DIRECT)
            try:
                robot = PyBulletRobot(self.model, client, collision_only=True)
                man = self.model.manipulator()
                fingers = link_box_spheres(robot, self.model, self.q_nominal, [n for n in man.links if "finger" in n])
                hand = link_box_spheres(robot, self.model, self.q_nominal, [n for n in man.links if "finger" not in n])
                body = body_obstacles(robot, self.model, self.q_nominal)
            finally:
                p.disconnect(client)
            self._probe = (fingers, hand, body)
        return self._probe

    @property
    def finger_inner(self) -> float:
        """[m] the open fingers' inner faces from the tool point along the closing axis, where they reach
        below an object's top (held ``GRASP_DEPTH`` deep): the PR2's probed ``FINGER_INNER``, else the
        nearest finger sphere to the axis among those that reach that deep."""
        if self.pr2:
            return FINGER_INNER
        man = self.model.manipulator()
        a, c = np.asarray(man.approach, float), np.asarray(man.closing, float)
        deep = [abs(float(x @ c)) - r for x, r in self._probed()[0] if float(x @ a) + r > -GRASP_DEPTH]
        return min(deep) if deep else 0.0

    def grasp_offset_max(self, obj: str) -> float:
        """How far [m] the object's centre may sit off the tool point along the closing axis: within the
        finger pads, and so that the open fingers (``FINGER_INNER``) stay ``RELEASE_CLEARANCE`` off its faces
        once it is let go (the hand lifts off past it). Negative: wider than the open gripper."""
        half = min(self.objects[obj].size[:2]) / 2
        # an object narrower than the pads is held at its centre: no offset, not "wider"
        return min(max(half - 0.015, 0.0), self.finger_inner - half - RELEASE_CLEARANCE)

    def too_wide(self) -> dict[str, float]:
        """Objects wider than the open gripper (``gripper_limits``: the rule the planners' entry check
        states), whose narrower side it cannot close round and let go of: name -> that width [m]."""
        limit = gripper_limits(self.scene.robot.name).max_width_m
        return {o: min(v.size[:2]) for o, v in self.objects.items() if min(v.size[:2]) > limit}

    def surface(self, support: str) -> tuple[FloatArray, tuple[float, float], float]:
        return target_surface(self.scene, support)

    # ----------------------------------------------------------------- the arm's shapes
    def arm_shapes(self, arm: str) -> ArmShapes:
        """The arm's spheres (see ``ArmShapes``), built once per arm."""
        if arm not in self._arm:
            self._arm[arm] = self._pr2_shapes(arm) if self.pr2 else self._model_shapes(arm)
        return self._arm[arm]

    def _pr2_shapes(self, arm: str) -> ArmShapes:
        """The PR2's: elbow, forearm, wrist, hand, two fingers, the upper arm (the first 7: against
        fixtures; the first 4: against the torso), the tool point (arm against arm only), then two points
        up the fingers (against objects, ``ColHO``)."""
        man = self.model.manipulator(arm)
        names = [self.model.joint_names[i] for i in self.model.group(man.group)]
        shoulder = next(n for n in names if "upper_arm_roll" in n)
        elbow = next(n for n in names if "elbow_flex" in n)
        wrist = next(n for n in names if "wrist_flex" in n)
        q7 = ca.SX.sym("q", len(self.arm_index(arm)))
        q = ca.SX(ca.DM(self.q_nominal))
        for k, i in enumerate(self.arm_index(arm)):
            q[int(i)] = q7[k]
        Ts, Te, Tw, Tt = self.model.casadi_fk((shoulder, elbow, wrist, man.tool_frame))(q)
        ps, pe, pw, pt = Ts[:3, 3], Te[:3, 3], Tw[:3, 3], Tt[:3, 3]
        closing = Tt[:3, :3] @ ca.DM(man.closing)
        approach = Tt[:3, :3] @ ca.DM(man.approach)
        pts = [pe, 0.5 * (pe + pw), pw, pt + 0.5 * (pw - pt), pt + 0.049 * closing, pt - 0.049 * closing]
        pts += [0.5 * (ps + pe), pt]
        # the open fingers widen above their tips (probed in the PyBullet PR2: the inner faces at
        # FINGER_INNER, the outer ones at 6 cm at the tip, 7 cm 3 cm up); between the tips and the
        # hand sphere a neighbouring block met them in the replay
        up = FINGER_UP * approach
        pts += [pt + 0.056 * closing - up, pt - 0.056 * closing - up]
        radii = (0.07, 0.06, 0.06, 0.045, 0.011, 0.011, 0.08, 0.035, 0.016, 0.016)
        fn = ca.Function(f"shapes_{arm}", [q7], [ca.horzcat(*pts), Tt])
        return ArmShapes(fn, radii, tuple(range(7)), (0, 1, 2, 3), (0, 1, 2, 6), (3, 4, 5, 8, 9), (0, 1, 2, 3, 6, 7))

    def _model_shapes(self, arm: str) -> ArmShapes:
        """From the model: spheres on the arm links' collision cylinders and at the wrist joint (the arm),
        and spheres covering the hand's and the open fingers' collision boxes (the hand); all of them
        against the fixtures. (The base footprint and the arm against its own base: ``_f_ColFix``.)"""
        man = self.model.manipulator(arm)
        z = ca.SX.sym("q", len(self.arm_index(arm)))
        rs = self._symbols(arm, z)
        links = arm_link_spheres(self.model, arm)
        wrist = next(n for n in (self.model.joint_names[i] for i in self.model.group(man.group)) if "wrist_flex" in n)
        frames = tuple(dict.fromkeys([*(f for f, _, _ in links), wrist]))
        Ts = self.model.casadi_fk(frames)(rs.q)
        Ts = dict(zip(frames, Ts if isinstance(Ts, (list, tuple)) else [Ts], strict=True))
        pts = [Ts[f][:3, :3] @ ca.DM(c) + Ts[f][:3, 3] for f, c, _ in links] + [Ts[wrist][:3, 3]]
        radii = [r for _, _, r in links] + [0.045]
        n_arm = len(pts)
        fingers, hand, _ = self._probed()
        for c, r in [*hand, *fingers]:
            pts.append(rs.T_tool[:3, :3] @ ca.DM(c) + rs.T_tool[:3, 3])
            radii.append(r)
        fn = ca.Function(f"shapes_{arm}", [z], [ca.horzcat(*pts), rs.T_tool])
        every, up_to_wrist = tuple(range(len(pts))), tuple(range(n_arm))
        return ArmShapes(fn, tuple(radii), every, (), up_to_wrist, tuple(range(n_arm, len(pts))), every)

    def _symbols(self, arm: str, z: ca.SX) -> RobotSymbols:
        """The robot at the mobile arm's variable z = [x, y, yaw, arm joints] (``nlp.factors``)."""
        return RobotSymbols(self.model, self.q_nominal, arm, z)

    # ----------------------------------------------------------------- factor functions
    def factor(self, key: tuple) -> FactorFn:
        """The function of a factor key, e.g. ("Kin", "b1", "right_arm"); see ``FACTOR_KINDS``."""
        if key not in self._fns:
            builder = getattr(self, f"_f_{key[0]}", None)
            if builder is None:
                raise RlgpError(f"unknown factor kind {key[0]!r}; valid: {FACTOR_KINDS}")
            ins, rows = builder(*key[1:])
            name = re.sub(r"[^0-9A-Za-z]+", "_", "_".join(key))  # CasADi's names: a drawer tag has ":+,"
            fn = ca.Function(name, ins, [ca.vertcat(*rows.g)])
            self._fns[key] = FactorFn(fn, np.asarray(rows.lower, float), np.asarray(rows.upper, float))
        return self._fns[key]

    def _f_Ref(self, obj: str):
        w, rows = ca.SX.sym("w", 4), Rows.empty()
        w0 = self.start_pose(obj)
        for i in range(3):
            rows.add(w[i] - w0[i], 0.0, 0.0)
        rows.add(ca.sin(w[3] - w0[3]), 0.0, 0.0)  # the same yaw (modulo pi: the same box)
        return [w], rows

    def _f_RefQ(self, arm: str):
        q, rows = ca.SX.sym("q", len(self.arm_index(arm))), Rows.empty()
        for i, v in enumerate(self.home_q(arm)):
            rows.add(q[i] - v, 0.0, 0.0)
        return [q], rows

    def _f_Place(self, obj: str, support: str):
        w, rows = ca.SX.sym("w", 4), Rows.empty()
        T, half, z = self.surface(support)
        size = self.objects[obj].size
        margin = max(size[0], size[1]) / 2
        rows.add(w[2] - (z + size[2] / 2 + PLACE_LIFT), 0.0, 0.0)
        R2 = T[:2, :2]
        lx = R2[0, 0] * (w[0] - T[0, 3]) + R2[1, 0] * (w[1] - T[1, 3])
        ly = R2[0, 1] * (w[0] - T[0, 3]) + R2[1, 1] * (w[1] - T[1, 3])
        rows.add(lx, -max(half[0] - margin, 0.0), max(half[0] - margin, 0.0))
        rows.add(ly, -max(half[1] - margin, 0.0), max(half[1] - margin, 0.0))
        return [w], rows

    def _f_On(self, obj: str, parent: str):
        w, wp, rows = ca.SX.sym("w", 4), ca.SX.sym("wp", 4), Rows.empty()
        h, hp = self.objects[obj].size[2], self.objects[parent].size[2]
        rows.add(w[2] - wp[2] - (h + hp) / 2 - PLACE_LIFT, 0.0, 0.0)
        c, s = ca.cos(wp[3]), ca.sin(wp[3])
        dx, dy = w[0] - wp[0], w[1] - wp[1]
        rows.add(c * dx + s * dy, -STACK_TOL, STACK_TOL)
        rows.add(-s * dx + c * dy, -STACK_TOL, STACK_TOL)
        return [w, wp], rows

    def _f_Grasp(self, obj: str):
        r, rows = ca.SX.sym("r", 4), Rows.empty()
        r0 = self.held_pose(obj)
        rows.add(r[0] - r0[0], 0.0, 0.0)  # the tool point GRASP_DEPTH below the top
        s_max = max(self.grasp_offset_max(obj), 0.0)
        rows.add(r[1], -s_max, s_max)  # across the finger pads: the open fingers clear of the faces
        if self.objects[obj].shape != "cylinder":  # a round side: the fingers close across it from any side
            rows.add(ca.sin(2 * r[2]), 0.0, 0.0)  # the fingers close across two opposite faces
        rows.add(r[3], -MAX_TILT, MAX_TILT)
        return [r], rows

    def _f_Kin(self, obj: str, arm: str):
        """The kinematic switch: the object's world pose w equals tool(q) * held pose r."""
        q, w, r, rows = ca.SX.sym("q", len(self.arm_index(arm))), ca.SX.sym("w", 4), ca.SX.sym("r", 4), Rows.empty()
        T_tool = self.arm_shapes(arm).fn(q)[1]
        upright_match(T_tool @ _rel_pose(r, self.upright(arm)), w, rows)
        return [q, w, r], rows

    def _f_Equal(self, dim: str):
        n = int(dim)
        a, b, rows = ca.SX.sym("a", n), ca.SX.sym("b", n), Rows.empty()
        for i in range(n):
            rows.add(a[i] - b[i], 0.0, 0.0)
        return [a, b], rows

    def _f_EqualBase(self, arm: str):
        """A mobile arm's base pose [x, y, yaw] the same at two time steps (the arm joints free)."""
        n = len(self.arm_index(arm))
        a, b, rows = ca.SX.sym("a", n), ca.SX.sym("b", n), Rows.empty()
        for i in range(3):
            rows.add(a[i] - b[i], 0.0, 0.0)
        return [a, b], rows

    def _f_SameBase(self, arm_a: str, arm_b: str):
        """Two arms on one mobile base: the base pose [x, y, yaw] in both arms' variables the same."""
        a = ca.SX.sym("a", len(self.arm_index(arm_a)))
        b, rows = ca.SX.sym("b", len(self.arm_index(arm_b))), Rows.empty()
        for i in range(3):
            rows.add(a[i] - b[i], 0.0, 0.0)
        return [a, b], rows

    def _f_ColFix(self, arm: str, drawers: str | None = None):
        """The arm clear of the fixtures; with ``drawers`` (a ``drawer_pntc.colfix`` tag) also of the drawers
        at their openings, the base of the open ones' footprints (without: the carcasses only)."""
        sh = self.arm_shapes(arm)
        q, rows = ca.SX.sym("q", len(self.arm_index(arm))), Rows.empty()
        boxes, open_rects = self.drawer_obstacles(drawers) if drawers else ([], [])
        P = sh.fn(q)[0]
        if self.pr2:  # the arm's own fingers: a wrist flexed further than this folds them onto the forearm
            names = [self.model.joint_names[i] for i in self.arm_index(arm)]
            for k, n in enumerate(names):
                if "wrist_flex" in n:
                    rows.add(q[k], WRIST_FLEX_MIN, ca.inf)
                if "shoulder_pan" in n:  # an arm crossing to the far side, or far out: its upper arm hits the torso
                    side = -1.0 if n.startswith("r_") else 1.0
                    rows.add(side * q[k], -PAN_CROSS_MAX, PAN_OUT_MAX)
        for b in [*self.fixture_boxes, *boxes]:
            Tinv = np.linalg.inv(b.T)
            for k in sh.fixture:
                pl = ca.DM(Tinv[:3, :3]) @ P[:, k] + ca.DM(Tinv[:3, 3])
                rows.add(box_sdf(pl, np.asarray(b.size) / 2), sh.radii[k], ca.inf)
        if self.mobile and self.body_boxes:  # the trunk boxes are in the base frame: the spheres into it
            c, s = ca.cos(q[2]), ca.sin(q[2])
            R_base_world = ca.vertcat(ca.horzcat(c, s, 0), ca.horzcat(-s, c, 0), ca.horzcat(0, 0, 1))
            P = R_base_world @ (P - ca.repmat(ca.vertcat(q[0], q[1], 0.0), 1, P.shape[1]))
        for b in self.body_boxes:  # the elbow, forearm, wrist and hand clear of the trunk
            Tinv = np.linalg.inv(b.T)
            for k in sh.trunk:
                pl = ca.DM(Tinv[:3, :3]) @ P[:, k] + ca.DM(Tinv[:3, 3])
                rows.add(box_sdf(pl, np.asarray(b.size) / 2), sh.radii[k], ca.inf)
        if self.mobile:  # the base footprint off the fixtures, the arm off its own base
            rs = self._symbols(arm, q)
            rects = [(np.asarray(fx.T), np.asarray(fx.size)) for fx in self.scene.fixtures] + open_rects
            footprint_clear(rs, rects, rows, margin=BASE_MARGIN)
            if not self.pr2:  # the PR2's arms clear its trunk by the boxes above
                self_clear(self.model, rs.q, arm_link_spheres(self.model, arm), self._probed()[2], rows)
        return [q], rows

    def _f_ColAA(self, arm_a: str, arm_b: str):
        sa, sb = self.arm_shapes(arm_a), self.arm_shapes(arm_b)
        qa, qb, rows = (
            ca.SX.sym("qa", len(self.arm_index(arm_a))),
            ca.SX.sym("qb", len(self.arm_index(arm_b))),
            Rows.empty(),
        )
        Pa, Pb = sa.fn(qa)[0], sb.fn(qb)[0]
        ia, ib = sa.other_arm, sb.other_arm  # PR2: elbow, forearm, wrist, hand, upper arm, tool (covering the fingers)
        points_apart(
            [Pa[:, k] for k in ia], [sa.radii[k] for k in ia], [Pb[:, k] for k in ib], [sb.radii[k] for k in ib], rows
        )
        return [qa, qb], rows

    def _arm_object(self, arm: str, obj: str, hand: bool, cabinet: str | None = None):
        sh = self.arm_shapes(arm)
        points = sh.hand if hand else sh.arm
        q, w, rows = ca.SX.sym("q", len(self.arm_index(arm))), ca.SX.sym("w", 4), Rows.empty()
        ww = w if cabinet is None else self._in_world_sx(cabinet, self.drawers[cabinet].travel, w)
        P = sh.fn(q)[0]
        half = np.asarray(self.objects[obj].size) / 2
        centres = [P[:, k] for k in points]
        if hand:  # each sphere swept LIFT up (a capsule): its point nearest the upright box in height
            centres = [ca.vertcat(c[0], c[1], ca.fmin(ca.fmax(ww[2], c[2]), c[2] + LIFT)) for c in centres]
        points_box_clear(centres, [sh.radii[k] for k in points], ww, half, rows)
        return [q, w], rows

    def _f_ColAO(self, arm: str, obj: str, cabinet: str | None = None):
        """The arm (upper arm, elbow, forearm, wrist) clear of a resting object (with ``cabinet``: one in
        that cabinet's open drawer, its pose in the drawer's frame)."""
        return self._arm_object(arm, obj, hand=False, cabinet=cabinet)

    def _f_ColHO(self, arm: str, obj: str, cabinet: str | None = None):
        """The hand and fingers clear of a resting object (not the one the hand has just let go), on the
        whole vertical line (``LIFT``) the hand descends along onto the keyframe and lifts off by: for an
        upright box and a vertical segment the nearest point is at the box centre's height clamped to
        the segment, so each sphere keeps one row."""
        return self._arm_object(arm, obj, hand=True, cabinet=cabinet)

    def _f_ColOO(self, obj_a: str, obj_b: str, cabinet: str | None = None):
        """Two upright boxes apart: a's centre outside b's box grown by a's footprint radius sideways and
        a's half height up and down (a Minkowski sum, exact vertically, conservative sideways). With
        ``cabinet``: both in its drawer (poses in one frame, the same rows), ``DROP_MARGIN`` apart."""
        wa, wb, rows = ca.SX.sym("wa", 4), ca.SX.sym("wb", 4), Rows.empty()
        sa, sb = self.objects[obj_a].size, self.objects[obj_b].size
        ra = math.hypot(sa[0], sa[1]) / 2
        grown = np.asarray(sb) / 2 + np.array([ra, ra, sa[2] / 2])
        points_box_clear([wa[:3]], [0.0], wb, grown, rows, margin=DROP_MARGIN if cabinet else 0.0)
        return [wa, wb], rows

    # ----------------------------------------------------------------- numeric helpers
    def tool_T(self, arm: str, q: FloatArray) -> FloatArray:
        """T_world_tool (4, 4) at the arm's variable q."""
        return np.asarray(self.arm_shapes(arm).fn(q)[1])

    def object_T(self, w: FloatArray) -> FloatArray:
        """The (4, 4) transform of an upright pose w = [x, y, z, yaw]."""
        return np.asarray(_YAW_POSE(w))


FACTOR_KINDS = (
    *("Ref", "RefQ", "Place", "On", "Grasp", "Kin", "Equal", "EqualBase", "SameBase"),
    *("ColFix", "ColAA", "ColAO", "ColHO", "ColOO"),
    *("Knob", "Drive", "Drop", "InDrawer"),
)
