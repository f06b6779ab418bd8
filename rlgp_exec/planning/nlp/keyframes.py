"""Level 2 of LGP: one NLP over every mode-switch configuration of a candidate action sequence.

For actions a_1..a_K the variables are the keyframes z_1..z_K (base and arm at each switch). Each
``pick`` puts the tool at a top grasp of its object (position, approach straight down, fingers across
two faces); the grasp is remembered as T_tool_obj = T_tool(z_pick)^-1 T_obj (the kinematic switch:
the object does not move relative to the hand while held). Each ``place`` then puts the object,
T_tool(z_place) T_tool_obj, upright on its target: resting on the surface, inside the region. Every
keyframe keeps the arm spheres clear of the fixtures and of the objects still where the scene put
them, and the base clear of fixture footprints. The objective is the weighted squared distance
between consecutive keyframes (from the start), a proxy for motion cost.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.nlp.factors import RobotSymbols, Rows, box_clear, footprint_clear, grasp_top, inside_rectangle
from rlgp_exec.reach.ik import ReachIK
from rlgp_exec.robot.model import FloatArray, RobotModel
from rlgp_exec.scene import Scene
from rlgp_exec.scene.geometry import fixture_boxes, object_box

__all__ = ["Action", "KeyframeResult", "solve_keyframes"]

log = logging.getLogger(__name__)
W_BASE = 3.0  # base motion weighs more than arm motion in the objective
W_TILT = 20.0  # a tilted grasp costs like ~2.5 m of base motion at full tilt: only when it must
FEAS_TOL = 1e-4
ATTEMPTS = 8  # initial guesses tried before a keyframe problem counts as infeasible
PLACE_LIFT = 0.005  # [m] an object is released this far above its support


@dataclass(frozen=True)
class Action:
    name: str  # "pick" | "place"
    obj: str
    target: str | None = None  # place: a region or a fixture

    def __str__(self) -> str:
        return f"({self.name} {self.obj}{' ' + self.target if self.target else ''})"


@dataclass(frozen=True)
class KeyframeResult:
    ok: bool
    keyframes: FloatArray  # (K, nq)
    object_poses: tuple[dict[str, FloatArray], ...]  # after each action: T_world_obj of every object
    cost: float
    violation: float
    solve_ms: float
    reason: str


def _rigid_inv(T: ca.SX) -> ca.SX:
    R, p = T[:3, :3], T[:3, 3]
    out = ca.SX.eye(4)
    out[:3, :3] = R.T
    out[:3, 3] = -R.T @ p
    return out


def _target_surface(scene: Scene, target: str) -> tuple[FloatArray, tuple[float, float], float]:
    """(T of the target rectangle's centre (4, 4), its half extents, its surface height [m])."""
    for r in scene.regions:
        if r.name == target:
            fx = scene.fixture(r.on)
            T = fx.T.copy()
            T[:3, 3] = (fx.T @ np.array([r.offset[0], r.offset[1], fx.size[2] / 2, 1.0]))[:3]
            return T, (r.size[0] / 2, r.size[1] / 2), float(T[2, 3])
    try:
        fx = scene.fixture(target)
    except KeyError:
        valid = sorted([r.name for r in scene.regions] + [f.name for f in scene.fixtures])
        raise RlgpError(f"place target {target!r} is not a region or fixture; valid: {valid}") from None
    T = fx.T.copy()
    T[2, 3] += fx.size[2] / 2
    return T, (fx.size[0] / 2, fx.size[1] / 2), float(T[2, 3])


def solve_keyframes(
    model: RobotModel,
    scene: Scene,
    q_start: FloatArray,
    actions: list[Action],
    manipulator: str | None = None,
    seed: int = 0,
    in_collision: Callable[[FloatArray], bool] | None = None,
    max_tilt: float = 0.0,
) -> KeyframeResult:
    """Solve the keyframe NLP (several initial guesses); ``in_collision(q)`` (the full PyBullet check,
    self-collisions included, which the NLP's shapes do not model) rejects a solution. ``max_tilt``
    [rad]: how far from vertical a grasp's approach may lean."""
    t0 = time.perf_counter()
    objs = {o.name: o for o in scene.objects}
    for a in actions:
        if a.name not in ("pick", "place"):
            raise RlgpError(f"keyframe NLP: unknown action {a.name!r}; valid: ['pick', 'place']")
        if a.obj not in objs:
            raise RlgpError(f"keyframe NLP: unknown object {a.obj!r}; valid: {sorted(objs)}")
    ik = ReachIK(model, scene, q_start, manipulator)
    n, K = len(ik.idx), len(actions)
    Z = ca.SX.sym("z", n, K)
    rows = Rows.empty()
    fixture_rects = [(fx.T, np.asarray(fx.size)) for fx in scene.fixtures]
    fixture_bx = [b for fx in scene.fixtures for b in fixture_boxes(fx)]
    poses: dict[str, FloatArray] = {name: o.T.copy() for name, o in objs.items()}
    moved: set[str] = set()
    held: str | None = None
    grasp: ca.SX | None = None
    targets: list[FloatArray] = []
    labels: list[str] = []  # one per constraint row, for the failure reason
    tilts: list[ca.SX] = []  # 1 + a_z of each grasp: a vertical hand carries objects most safely
    rng = np.random.default_rng(seed)
    for k, a in enumerate(actions):
        rs = RobotSymbols(model, q_start, manipulator, Z[:, k])
        still = [object_box(objs[m]) for m in objs if m not in moved and m != a.obj]
        n0 = len(rows.g)
        box_clear(rs, fixture_bx + [b.__class__(b.name, b.size, poses[b.name], b.color) for b in still], rows)
        labels += [f"{a} clearance"] * (len(rows.g) - n0)
        n0 = len(rows.g)
        footprint_clear(rs, fixture_rects, rows, margin=0.01)
        labels += [f"{a} base footprint"] * (len(rows.g) - n0)
        n0 = len(rows.g)
        o = objs[a.obj]
        if a.name == "pick":
            if held is not None:
                raise RlgpError(f"keyframe NLP: {a} while holding {held}")
            tilts.append(grasp_top(rs, poses[a.obj], o.size, rows, max_tilt=max_tilt))
            grasp = _rigid_inv(rs.T_tool) @ ca.DM(poses[a.obj])
            held = a.obj
            targets.append(poses[a.obj][:3, 3] + np.array([0.0, 0.0, o.size[2] / 2]))
        else:
            if held != a.obj or grasp is None or a.target is None:
                raise RlgpError(f"keyframe NLP: {a} without holding {a.obj} (holding {held})")
            T_obj = rs.T_tool @ grasp
            T_tgt, half, z_surf = _target_surface(scene, a.target)
            margin = max(o.size[0], o.size[1]) / 2
            inside_rectangle(T_obj[:2, 3], T_tgt, (max(half[0] - margin, 0.0), max(half[1] - margin, 0.0)), rows)
            rows.add(T_obj[2, 3] - (z_surf + o.size[2] / 2 + PLACE_LIFT), 0.0, 0.0)
            rows.add(T_obj[2, 2], 0.999, 1.0)  # upright
            moved.add(a.obj)
            held, grasp = None, None
            targets.append(T_tgt[:3, 3] + np.array([0.0, 0.0, o.size[2]]))
        labels += [f"{a} {'grasp' if a.name == 'pick' else 'placement'}"] * (len(rows.g) - n0)
    z0 = ca.DM(ik.z_of(q_start))
    cost = 0
    prev = z0
    for k in range(K):
        d = Z[:, k] - prev
        cost += W_BASE * ca.sumsqr(d[:2]) + W_BASE * d[2] ** 2 + ca.sumsqr(d[3:])
        prev = Z[:, k]
    cost += W_TILT * sum(tilts)
    nlp = {"x": ca.vec(Z), "f": cost, "g": ca.vertcat(*rows.g)}
    solver = ca.nlpsol(
        "keyframes",
        "ipopt",
        nlp,
        {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes", "ipopt.max_iter": 400, "ipopt.tol": 1e-7},
    )
    lbx = np.tile(ik.lo, K)
    ubx = np.tile(ik.hi, K)
    best = None
    for _attempt in range(ATTEMPTS):  # initial guesses: each keyframe from position IK at its target
        init = []
        for x in targets:
            yaw = rng.uniform(-math.pi, math.pi)
            r = ik.solve(x, ik.guess(x, yaw))
            init.append(ik.z_of(r.q) if r.ok else ik.guess(x, yaw))
        res = solver(x0=np.concatenate(init), lbx=lbx, ubx=ubx, lbg=rows.lower, ubg=rows.upper)
        g = np.asarray(res["g"]).reshape(-1)
        viol = float(np.max(np.r_[np.asarray(rows.lower) - g, g - np.asarray(rows.upper), 0.0]))
        over = np.maximum(np.asarray(rows.lower) - g, g - np.asarray(rows.upper))
        worst = labels[int(np.argmax(over))] if g.size else ""
        if viol <= FEAS_TOL and in_collision is not None:
            zk = np.asarray(ca.reshape(res["x"], n, K)).T
            bad = [k for k in range(K) if in_collision(ik.q_of(zk[k]))]
            if bad:  # feasible for the NLP, not for the robot: try another start
                viol, worst = 1.0, f"{actions[bad[0]]} keyframe collides in PyBullet (self or world)"
        cand = (viol, float(res["f"]), np.asarray(res["x"]).reshape(-1), worst)
        if best is None or (cand[0] < best[0] - 1e-9) or (cand[0] <= FEAS_TOL and cand[1] < best[1]):
            best = cand
        if viol <= FEAS_TOL:
            break
    viol, f, zflat, worst_row = best  # type: ignore[misc]
    zs = np.asarray(ca.reshape(ca.DM(zflat), n, K)).T  # ca.vec is column-major: column k is keyframe k
    keyframes = np.array([ik.q_of(z) for z in zs])
    # object poses after each action, evaluated numerically
    out_poses, cur, held_T = [], {k2: v.copy() for k2, v in poses.items()}, None
    for k, a in enumerate(actions):
        T_tool = model.fk(keyframes[k], ik.tool)
        if a.name == "pick":
            held_T = np.linalg.inv(T_tool) @ cur[a.obj]
        else:
            cur[a.obj] = T_tool @ held_T
        out_poses.append({k2: v.copy() for k2, v in cur.items()})
    ok = viol <= FEAS_TOL
    return KeyframeResult(
        ok,
        keyframes,
        tuple(out_poses),
        f,
        viol,
        (time.perf_counter() - t0) * 1e3,
        "ok" if ok else f"constraints violated by {viol:.2e} (worst: {worst_row})",
    )
