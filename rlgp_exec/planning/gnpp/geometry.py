"""The constraint functions h_b of the GNPP graph-NLP, one CasADi ``Function`` per kind and arguments.

Continuous variables (paper Sec. IV-A): an arm's joints ``q`` (7,) [rad] (base and torso fixed at the
scene's start), and an object's pose ``x`` (4,) = [x, y, z, yaw] [m, rad] relative to its parent: the
world when it rests (on a fixture, a region or another object), the holding arm's tool frame when
held (then the object's z axis is the tool's -approach axis, see ``T_TOOL_UPRIGHT``).

Each function is built once from the shared factors (``planning.nlp.factors``) and cached, so an NLP
of any subgraph is a composition of cached functions (their derivatives are cached too).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.nlp.factors import Rows, points_apart, points_box_clear, upright_match, yaw_pose
from rlgp_exec.planning.nlp.keyframes import _target_surface
from rlgp_exec.reach import nominal_q
from rlgp_exec.reach.ik import box_sdf
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import Box, fixture_boxes

__all__ = ["GRASP_DEPTH", "MAX_TILT", "PLACE_LIFT", "T_TOOL_UPRIGHT", "FactorFn", "FactorLib"]

log = logging.getLogger(__name__)

PLACE_LIFT = 0.003  # [m] an object is released this far above its support
GRASP_DEPTH = 0.025  # [m] the tool point below an object's top (at most half its height)
MAX_TILT = 0.9  # [rad] a grasping hand leans at most this far from vertical
WRIST_FLEX_MIN = -1.65  # [rad] (PR2) beyond it the open fingers touch the forearm at some rolls
PAN_CROSS_MAX = 0.1  # [rad] (PR2) shoulder pan towards the other arm's side at most
#: (PR2) the open fingertips' inner faces this far from the tool point along the closing axis [m]:
#: probed in the PyBullet model at the 0.5 rad finger opening every plan keeps
FINGER_INNER = 0.0375
FINGER_CLEAR = 0.003  # [m] an object let go keeps this much from the open fingers (replay tolerance 2 mm)
FINGER_UP = 0.025  # [m] the second point of each open finger, this far above its tip (PR2 finger links)
STACK_TOL = 0.012  # [m] a stacked object's centre within this of its parent's axis (x and y)
#: object frame in the tool frame for an upright object held from above (tool x = approach = down)
T_TOOL_UPRIGHT = np.array([[0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]])


@dataclass(frozen=True)
class FactorFn:
    fn: ca.Function  # inputs: the variables in slot order; output: the rows g
    lower: FloatArray
    upper: FloatArray


def _rel_pose(r: ca.SX) -> ca.SX:
    """T_tool_obj of the held pose r = [d, s, psi, theta]: the object's centre d below the tool point
    along the object's axis, shifted s along the fingers (tool y), turned psi about its own axis and
    tilted theta about the fingers' axis (a leaning hand reaches further across a table)."""
    c, s = ca.cos(r[2]), ca.sin(r[2])
    Rz = ca.vertcat(ca.horzcat(c, -s, 0), ca.horzcat(s, c, 0), ca.horzcat(0, 0, 1))
    ct, st = ca.cos(r[3]), ca.sin(r[3])
    Ry = ca.vertcat(ca.horzcat(ct, 0, st), ca.horzcat(0, 1, 0), ca.horzcat(-st, 0, ct))
    R = Ry @ ca.DM(T_TOOL_UPRIGHT) @ Rz
    T = ca.SX.eye(4)
    T[:3, :3] = R
    T[:3, 3] = -r[0] * R[:, 2] + r[1] * ca.DM([0.0, 1.0, 0.0])
    return T


_W = ca.SX.sym("w", 4)
_YAW_POSE = ca.Function("yaw_pose", [_W], [yaw_pose(_W)])


class FactorLib:
    """The scene's factor functions and variable bounds (PR2: both arms; base and torso fixed)."""

    def __init__(self, model: RobotModel, scene: Scene) -> None:
        self.model, self.scene = model, scene
        self.q_nominal = nominal_q(model, scene)
        self.arms = tuple(m.name for m in model.config.manipulators)
        self.objects = {o.name: o for o in scene.objects}
        self._fns: dict[tuple, FactorFn] = {}
        self._arm: dict[str, tuple] = {}
        self.fixture_boxes = [b for fx in scene.fixtures for b in fixture_boxes(fx)]
        self.body_boxes = self._body_boxes()

    def _body_boxes(self) -> list[Box]:
        """The robot's own trunk as boxes (world frame) that its arms must clear (PR2: the torso,
        from its collision hull's bounding box in the base frame [m])."""
        if self.model.config.name != "pr2":
            return []
        x, y, yaw = self.q_nominal[:3]
        lift = self.q_nominal[self.model.index("torso_lift_joint")]
        T = np.eye(4)
        T[:2, :2] = [[math.cos(yaw), -math.sin(yaw)], [math.sin(yaw), math.cos(yaw)]]
        centre = np.array([-0.15, 0.0, 0.69 + lift])  # base frame: x forward
        T[:3, 3] = np.array([x, y, 0.0]) + T[:3, :3] @ centre
        return [Box("torso", (0.36, 0.5, 0.8), T, (0.5, 0.5, 0.5, 1.0))]

    # ----------------------------------------------------------------- variables
    def arm_index(self, arm: str) -> FloatArray:
        return np.array(self.model.group(self.model.manipulator(arm).group), dtype=int)

    def var_bounds(self, kind: str, owner: str) -> tuple[FloatArray, FloatArray]:
        if kind == "q":
            idx = self.arm_index(owner)
            lo = np.maximum(self.model.limits.lower[idx], -2 * math.pi)
            hi = np.minimum(self.model.limits.upper[idx], 2 * math.pi)
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

        ctx = {("Ref", o): digest(self.start_pose(o)) for o in self.objects}
        ctx.update({("RefQ", m): digest(self.home_q(m)) for m in self.arms})
        return ctx

    def start_pose(self, obj: str) -> FloatArray:
        o = self.objects[obj]
        return np.array([o.pose[0], o.pose[1], o.pose[2], o.pose[3]], float)

    def held_pose(self, obj: str) -> FloatArray:
        """The nominal held pose r = [d, s, psi, theta]: tool point GRASP_DEPTH below the top, centred,
        hand vertical."""
        h = self.objects[obj].size[2]
        return np.array([h / 2 - min(GRASP_DEPTH, h / 2), 0.0, 0.0, 0.0])

    def grasp_offset_max(self, obj: str) -> float:
        """How far [m] the object's centre may sit off the tool point along the closing axis: within the
        finger pads, and so that the open fingers (``FINGER_INNER``) stay ``FINGER_CLEAR`` off its faces
        once it is let go (the hand lifts off past it). Negative: wider than the open gripper."""
        half = min(self.objects[obj].size[:2]) / 2
        return min(half - 0.015, FINGER_INNER - half - FINGER_CLEAR)

    def too_wide(self) -> dict[str, float]:
        """Objects the open gripper cannot close round (and let go) without touching: name -> width [m]."""
        return {o: min(v.size[:2]) for o, v in self.objects.items() if self.grasp_offset_max(o) < 0.0}

    def surface(self, support: str) -> tuple[FloatArray, tuple[float, float], float]:
        return _target_surface(self.scene, support)

    # ----------------------------------------------------------------- the arm's shapes
    def arm_shapes(self, arm: str) -> tuple[ca.Function, list[float], int]:
        """(q (7,) -> (points (3, K) world, T_tool), radii, n_body): elbow, forearm, wrist, hand, two
        fingers, the upper arm (the first ``n_body``: against objects and fixtures too), then the tool
        point (arm against arm only), then two points up the fingers (against objects, ``ColHO``)."""
        if arm not in self._arm:
            man = self.model.manipulator(arm)
            names = [self.model.joint_names[i] for i in self.model.group(man.group)]
            shoulder = next(n for n in names if "upper_arm_roll" in n)
            elbow = next(n for n in names if "elbow_flex" in n)
            wrist = next(n for n in names if "wrist_flex" in n)
            q7 = ca.SX.sym("q", len(names))
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
            radii = [0.07, 0.06, 0.06, 0.045, 0.011, 0.011, 0.08, 0.035, 0.016, 0.016]
            fn = ca.Function(f"shapes_{arm}", [q7], [ca.horzcat(*pts), Tt])
            self._arm[arm] = (fn, radii, 7)
        return self._arm[arm]

    # ----------------------------------------------------------------- factor functions
    def factor(self, key: tuple) -> FactorFn:
        """The function of a factor key, e.g. ("Kin", "b1", "right_arm"); see ``FACTOR_KINDS``."""
        if key not in self._fns:
            builder = getattr(self, f"_f_{key[0]}", None)
            if builder is None:
                raise RlgpError(f"unknown factor kind {key[0]!r}; valid: {FACTOR_KINDS}")
            ins, rows = builder(*key[1:])
            fn = ca.Function("_".join(key), ins, [ca.vertcat(*rows.g)])
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
        rows.add(ca.sin(2 * r[2]), 0.0, 0.0)  # the fingers close across two opposite faces
        rows.add(r[3], -MAX_TILT, MAX_TILT)
        return [r], rows

    def _f_Kin(self, obj: str, arm: str):
        """The kinematic switch: the object's world pose w equals tool(q) * held pose r."""
        fn, _, _ = self.arm_shapes(arm)
        q, w, r, rows = ca.SX.sym("q", len(self.arm_index(arm))), ca.SX.sym("w", 4), ca.SX.sym("r", 4), Rows.empty()
        T_tool = fn(q)[1]
        upright_match(T_tool @ _rel_pose(r), w, rows)
        return [q, w, r], rows

    def _f_Equal(self, dim: str):
        n = int(dim)
        a, b, rows = ca.SX.sym("a", n), ca.SX.sym("b", n), Rows.empty()
        for i in range(n):
            rows.add(a[i] - b[i], 0.0, 0.0)
        return [a, b], rows

    def _f_ColFix(self, arm: str):
        fn, radii, nb = self.arm_shapes(arm)
        q, rows = ca.SX.sym("q", len(self.arm_index(arm))), Rows.empty()
        P = fn(q)[0]
        # the arm's own fingers: a wrist flexed further than this folds them onto the forearm (PR2)
        names = [self.model.joint_names[i] for i in self.arm_index(arm)]
        for k, n in enumerate(names):
            if "wrist_flex" in n:
                rows.add(q[k], WRIST_FLEX_MIN, ca.inf)
            if "shoulder_pan" in n:  # an arm crossing to the far side hits the torso with its upper arm
                side = -1.0 if n.startswith("r_") else 1.0
                rows.add(side * q[k], -PAN_CROSS_MAX, ca.inf)
        for b in self.fixture_boxes:
            Tinv = np.linalg.inv(b.T)
            for k in range(nb):
                pl = ca.DM(Tinv[:3, :3]) @ P[:, k] + ca.DM(Tinv[:3, 3])
                rows.add(box_sdf(pl, np.asarray(b.size) / 2), radii[k], ca.inf)
        for b in self.body_boxes:  # the elbow, forearm, wrist and hand clear of the trunk
            Tinv = np.linalg.inv(b.T)
            for k in range(4):
                pl = ca.DM(Tinv[:3, :3]) @ P[:, k] + ca.DM(Tinv[:3, 3])
                rows.add(box_sdf(pl, np.asarray(b.size) / 2), radii[k], ca.inf)
        return [q], rows

    def _f_ColAA(self, arm_a: str, arm_b: str):
        fa, ra, _ = self.arm_shapes(arm_a)
        fb, rb, _ = self.arm_shapes(arm_b)
        qa, qb, rows = (
            ca.SX.sym("qa", len(self.arm_index(arm_a))),
            ca.SX.sym("qb", len(self.arm_index(arm_b))),
            Rows.empty(),
        )
        Pa, Pb = fa(qa)[0], fb(qb)[0]
        ia = ib = [0, 1, 2, 3, 6, 7]  # elbow, forearm, wrist, hand, upper arm, tool (covering the fingers)
        points_apart([Pa[:, k] for k in ia], [ra[k] for k in ia], [Pb[:, k] for k in ib], [rb[k] for k in ib], rows)
        return [qa, qb], rows

    def _arm_object(self, arm: str, obj: str, points: tuple[int, ...]):
        fn, radii, _ = self.arm_shapes(arm)
        q, w, rows = ca.SX.sym("q", len(self.arm_index(arm))), ca.SX.sym("w", 4), Rows.empty()
        P = fn(q)[0]
        half = np.asarray(self.objects[obj].size) / 2
        points_box_clear([P[:, k] for k in points], [radii[k] for k in points], w, half, rows)
        return [q, w], rows

    def _f_ColAO(self, arm: str, obj: str):
        """The arm (upper arm, elbow, forearm, wrist) clear of a resting object."""
        return self._arm_object(arm, obj, (0, 1, 2, 6))

    def _f_ColHO(self, arm: str, obj: str):
        """The hand and fingers clear of a resting object (not the one the hand has just let go)."""
        return self._arm_object(arm, obj, (3, 4, 5, 8, 9))

    def _f_ColOO(self, obj_a: str, obj_b: str):
        """Two upright boxes apart: a's centre outside b's box grown by a's footprint radius sideways and
        a's half height up and down (a Minkowski sum, exact vertically, conservative sideways)."""
        wa, wb, rows = ca.SX.sym("wa", 4), ca.SX.sym("wb", 4), Rows.empty()
        sa, sb = self.objects[obj_a].size, self.objects[obj_b].size
        ra = math.hypot(sa[0], sa[1]) / 2
        grown = np.asarray(sb) / 2 + np.array([ra, ra, sa[2] / 2])
        points_box_clear([wa[:3]], [0.0], wb, grown, rows)
        return [wa, wb], rows

    # ----------------------------------------------------------------- numeric helpers
    def tool_T(self, arm: str, q7: FloatArray) -> FloatArray:
        return np.asarray(self.arm_shapes(arm)[0](q7)[1])

    def object_T(self, w: FloatArray) -> FloatArray:
        """The (4, 4) transform of an upright pose w = [x, y, z, yaw]."""
        return np.asarray(_YAW_POSE(w))


FACTOR_KINDS = ("Ref", "RefQ", "Place", "On", "Grasp", "Kin", "Equal", "ColFix", "ColAA", "ColAO", "ColHO", "ColOO")
