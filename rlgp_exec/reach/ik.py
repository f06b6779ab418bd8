"""Node validation (R-LGP Eq. 2): whole-body IK for an end-effector position, as one CasADi NLP.

Variables are the planar base and the manipulator's joints, z = [x, y, yaw, q_arm] (Eq. 1); every
other joint stays at the nominal configuration. The NLP

    min_z  |f_kin(z) - x0|^2 + w_reg |q_arm - q_arm_ref|^2
    s.t.   joint limits;  base footprint clear of every fixture footprint (smooth signed distance)

is solved by IPOPT from a warm start (a neighbouring node's configuration, or the base placed so that
the arm's home reach lands on x0). The precondition g_prec (Eq. 2) is checked first: a target inside a
fixture is rejected without solving. The solution is then collision-checked in PyBullet (the whole
robot against the fixtures and itself); only then is it a node n(x, q, c).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import casadi as ca
import numpy as np

from rlgp_exec.ipopt import LEAN
from rlgp_exec.planning import budget
from rlgp_exec.planning.margins import FEAS_TOL, TOOL_POS_TOL
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import fixture_boxes

__all__ = ["IKResult", "ReachIK", "arm_spheres", "base_circles"]

log = logging.getLogger(__name__)
POS_TOL = TOOL_POS_TOL  # [m] a node's q must put the tool within this of x0
MEMO_SIZE = 20_000  # IK answers remembered per solver (the same target and start recur within a plan)
W_REG = 1e-4  # weight of the arm posture regulariser (small: it must not pull the tool off x0)
IK_TOL = 1e-5  # IPOPT's tolerance: loose enough to be quick, tight enough to keep the tool within POS_TOL


@dataclass(frozen=True)
class IKResult:
    ok: bool
    q: FloatArray  # (nq,) the whole configuration
    cost: float  # the NLP's objective at the solution (c of n(x, q, c))
    err: float  # |f_kin(q) - x0| [m]
    reason: str


def base_circles(model: RobotModel) -> list[tuple[float, float, float]]:
    """(x, y, r) circles [m] in the base frame covering the base footprint: one for a round base,
    four (one per quadrant, each circumscribing it) for a rectangular one."""
    b = model.config.base
    if b.footprint_radius is not None:
        return [(0.0, 0.0, float(b.footprint_radius))]
    hx, hy = b.footprint_half_extents  # type: ignore[misc]
    r = math.hypot(hx / 2, hy / 2)
    return [(sx * hx / 2, sy * hy / 2, r) for sx in (-1, 1) for sy in (-1, 1)]


def arm_spheres(model: RobotModel, manipulator: str | None = None, radius: float = 0.07) -> list[tuple[str, float]]:
    """(frame, radius [m]) spheres along a manipulator: its joints from the second on, the palm and the tool."""
    m = model.manipulator(manipulator)
    joints = [model.joint_names[i] for i in model.group(m.group)][1:]
    return [(j, radius) for j in joints] + [(m.palm_frame, radius), (m.tool_frame, 0.5 * radius)]


def box_sdf(p_local: ca.SX | ca.DM, half: np.ndarray) -> ca.SX:
    """Smooth signed distance [m] from a point (in the box frame) to a box of half extents ``half``:
    the exact distance outside (up to 1e-4 m of smoothing), negative and ~ -depth inside. One call of
    a CasADi function built once (the expression inlined: ~20x faster to build than op by op)."""
    return _box_sdf_fn()(p_local, ca.DM(np.asarray(half, float).reshape(3)))


def box_sdf_columns(R_p: ca.SX, t: np.ndarray, half: np.ndarray) -> ca.SX:
    """``box_sdf`` of every column of R_p + t (R_p (3, N): points already rotated into the box frame,
    t (3,) the box frame's offset): (1, N), one mapped call."""
    n = int(R_p.shape[1])
    offset = ca.repmat(ca.DM(np.asarray(t, float).reshape(3)), 1, n)
    halves = ca.repmat(ca.DM(np.asarray(half, float).reshape(3)), 1, n)
    return _box_sdf_fn().map(n)(R_p + offset, halves)


_BOX_SDF: list[ca.Function] = []


def _box_sdf_fn() -> ca.Function:
    if not _BOX_SDF:
        p, half = ca.SX.sym("p", 3), ca.SX.sym("half", 3)
        d = [ca.sqrt(p[i] ** 2 + 1e-9) - half[i] for i in range(3)]
        outside = ca.sqrt(sum(_smooth_pos(di) ** 2 for di in d) + 1e-8)
        inside = -_smooth_pos(-ca.fmax(ca.fmax(d[0], d[1]), d[2]))
        _BOX_SDF.append(ca.Function("box_sdf", [p, half], [outside + inside]))
    return _BOX_SDF[0]


def _smooth_pos(a: ca.SX, eps: float = 1e-6) -> ca.SX:
    return 0.5 * (a + ca.sqrt(a * a + eps))


class ReachIK:
    """Position IK over the base and one manipulator, with base-vs-fixture clearance constraints."""

    def __init__(
        self,
        model: RobotModel,
        scene: Scene,
        q_nominal: FloatArray,
        manipulator: str | None = None,
        clearance: float = 0.03,
        tol: float = IK_TOL,
    ) -> None:
        """``clearance`` [m]: the base circles' extra room from fixture footprints; ``tol``: IPOPT's."""
        self.model = model
        self.manip = model.manipulator(manipulator)
        self.tool = self.manip.tool_frame
        self.idx = np.array([*model.group("base"), *model.group(self.manip.group)], dtype=int)
        self.q_nominal = np.asarray(q_nominal, float).copy()
        n = len(self.idx)
        lo, hi = model.limits.lower[self.idx].copy(), model.limits.upper[self.idx].copy()
        lo[2], hi[2] = -3 * math.pi, 3 * math.pi  # yaw: continuous, wrapped afterwards
        self.lo, self.hi = lo, hi
        z, p = ca.SX.sym("z", n), ca.SX.sym("p", n)  # p = [x0 (3), q_arm_ref (n - 3)]
        q = ca.SX(ca.DM(self.q_nominal))
        for k, i in enumerate(self.idx):
            q[int(i)] = z[k]
        T = model.casadi_fk((self.tool,))(q)
        pos = T[:3, 3]
        f = ca.sumsqr(pos - p[:3]) + W_REG * ca.sumsqr(z[3:] - p[3:])
        g, self.g_lo = [], []
        c, s = ca.cos(z[2]), ca.sin(z[2])
        self.fixtures = [(fx.name, np.asarray(fx.T), np.asarray(fx.size)) for fx in scene.fixtures]
        self._fixture_boxes = [(fx.name, fixture_boxes(fx)) for fx in scene.fixtures]
        for _, Tf, size in self.fixtures:
            R2 = Tf[:2, :2]
            for cx, cy, r in base_circles(model):
                wx, wy = z[0] + c * cx - s * cy, z[1] + s * cx + c * cy  # circle centre, world
                lx = R2[0, 0] * (wx - Tf[0, 3]) + R2[1, 0] * (wy - Tf[1, 3])  # in the fixture frame
                ly = R2[0, 1] * (wx - Tf[0, 3]) + R2[1, 1] * (wy - Tf[1, 3])
                dx = _smooth_pos(ca.sqrt(lx * lx + 1e-9) - size[0] / 2)
                dy = _smooth_pos(ca.sqrt(ly * ly + 1e-9) - size[1] / 2)
                g.append(ca.sqrt(dx * dx + dy * dy + 1e-9))
                self.g_lo.append(r + clearance)
        # arm spheres stay clear of every fixture box (the paper's g(q) collision inequalities)
        spheres = arm_spheres(model, manipulator)
        Ts = model.casadi_fk(tuple(fr for fr, _ in spheres))(q)
        Ts = Ts if isinstance(Ts, (list, tuple)) else [Ts]
        for _, boxes in self._fixture_boxes:
            for b in boxes:
                Tinv = np.linalg.inv(b.T)
                for (_, r), Tk in zip(spheres, Ts, strict=True):
                    pl = ca.DM(Tinv[:3, :3]) @ Tk[:3, 3] + ca.DM(Tinv[:3, 3])
                    g.append(box_sdf(pl, np.asarray(b.size) / 2))
                    self.g_lo.append(r)
        # common subexpressions merged (the arm's kinematics once, not once per fixture box): the same
        # answers, ~5-10 % less time per solve
        nlp = {"x": z, "p": p, "f": f, "g": ca.cse(ca.vertcat(*g)) if g else ca.SX(0, 1)}
        opts: dict[str, bool | int | float | str] = {
            "ipopt.print_level": 0,
            "print_time": False,
            "ipopt.sb": "yes",
            "ipopt.max_iter": 100,
            "ipopt.tol": tol,
            "ipopt.acceptable_tol": max(tol, 1e-5),
            "ipopt.mu_init": 1e-3,
        }
        self._solver = ca.nlpsol("reach_ik", "ipopt", nlp, {**opts, **LEAN})
        self.clearance = clearance
        self._fk_pos = ca.Function("fk_pos", [z], [pos])
        self.home_arm = model.home()[self.idx[3:]]
        T_home = model.fk(model.home(), self.tool)  # the tool's position in the base frame at home
        self.reach_xy = T_home[:2, 3].copy()
        self.reach = float(np.linalg.norm(self.reach_xy))
        self._memo: dict[bytes, IKResult] = {}

    # ------------------------------------------------------------------ helpers
    def inside_fixture(self, x0: FloatArray, margin: float = 0.01) -> str | None:
        """g_prec: the name of the fixture box containing ``x0`` (inflated by ``margin``), if any."""
        for fx_name, boxes in self._fixture_boxes:
            for b in boxes:
                p = np.linalg.inv(b.T) @ np.r_[x0, 1.0]
                if np.all(np.abs(p[:3]) <= np.asarray(b.size) / 2 + margin):
                    return fx_name
        return None

    def base_clear(self, q: FloatArray) -> bool:
        """The NLP's base constraint at q: every base circle ``clearance`` [m] beyond its radius from
        every fixture footprint (exactly; the NLP's is smoothed by ~1e-3 m)."""
        c, s = math.cos(q[self.idx[2]]), math.sin(q[self.idx[2]])
        bx, by = q[self.idx[0]], q[self.idx[1]]
        for _, Tf, size in self.fixtures:
            for cx, cy, r in base_circles(self.model):
                w = np.array([bx + c * cx - s * cy, by + s * cx + c * cy]) - Tf[:2, 3]
                local = np.abs(Tf[:2, :2].T @ w) - np.asarray(size[:2]) / 2
                if float(np.linalg.norm(np.maximum(local, 0.0))) < r + self.clearance:
                    return False
        return True

    def node_at(self, q: FloatArray) -> tuple[FloatArray, float] | None:
        """A node for a configuration found otherwise than by Eq. 2 (sampled): (x, c), x the tool's
        position and c Eq. 2's objective for that target (its posture term), if q is within the
        limits and its base keeps the NLP's clearance; else None. The robot's collisions are the
        caller's, as for ``solve``."""
        z = np.asarray(q, float)[self.idx]
        if np.any(z[3:] < self.lo[3:]) or np.any(z[3:] > self.hi[3:]) or not self.base_clear(q):
            return None
        x = self.model.fk(q, self.tool)[:3, 3]
        return x, W_REG * float(np.sum((z[3:] - self.home_arm) ** 2))

    def guess(self, x0: FloatArray, yaw: float) -> FloatArray:
        """z (n,): the base facing ``yaw`` placed so the arm's home reach lands on x0."""
        c, s = math.cos(yaw), math.sin(yaw)
        off = np.array([c * self.reach_xy[0] - s * self.reach_xy[1], s * self.reach_xy[0] + c * self.reach_xy[1]])
        return np.r_[x0[:2] - off, yaw, self.home_arm]

    def z_of(self, q: FloatArray) -> FloatArray:
        return np.asarray(q, float)[self.idx].copy()

    def q_of(self, z: FloatArray) -> FloatArray:
        q = self.q_nominal.copy()
        q[self.idx] = z
        return self.model.limits.wrap(q)

    def solve(self, x0: FloatArray, z_init: FloatArray, fix_base: bool = False) -> IKResult:
        """Solve Eq. 2 for target ``x0`` (3,) from ``z_init``; ok when the tool reaches x0 within POS_TOL
        and the base clearance holds (PyBullet collision checking is the caller's). ``fix_base`` keeps
        the base where z_init has it."""
        x0 = np.asarray(x0, float)
        z0 = np.clip(np.asarray(z_init, float), self.lo, self.hi)
        # IPOPT is deterministic: the same target from the same start has the same answer (keyframe
        # starts repeat across a sequence's tilts and across candidates sharing an action)
        key = x0.tobytes() + z0.tobytes()
        hit = self._memo.get(key)
        if hit is not None:
            return replace(hit, q=hit.q.copy())
        out = self._solve(x0, z0)
        if len(self._memo) < MEMO_SIZE:
            self._memo[key] = replace(out, q=out.q.copy())
        return out

    def _solve(self, x0: FloatArray, z0: FloatArray) -> IKResult:
        """One IPOPT run of Eq. 2 (``solve`` without the memo)."""
        budget.check()
        res = self._solver(
            x0=z0,
            p=np.r_[x0, self.home_arm],
            lbx=self.lo,
            ubx=self.hi,
            lbg=np.asarray(self.g_lo),
            ubg=np.full(len(self.g_lo), np.inf),
        )
        z = np.asarray(res["x"]).reshape(-1)
        err = float(np.linalg.norm(np.asarray(self._fk_pos(z)).reshape(-1) - x0))
        g = np.asarray(res["g"]).reshape(-1)
        if not np.all(np.isfinite(z)):
            return IKResult(False, self.q_nominal, math.inf, math.inf, "NaN in the IK solution")
        if err > POS_TOL:
            return IKResult(False, self.q_of(z), float(res["f"]), err, f"tool {err * 1e3:.1f} mm from the target")
        if g.size and np.any(g < np.asarray(self.g_lo) - FEAS_TOL):
            return IKResult(False, self.q_of(z), float(res["f"]), err, "the robot's shapes overlap a fixture")
        return IKResult(True, self.q_of(z), float(res["f"]), err, "ok")
