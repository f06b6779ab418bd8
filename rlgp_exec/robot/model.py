"""``RobotModel``: one kinematic model per robot, serving planning, timing, perception and sim.

The configuration vector is ``q = [x, y, yaw, q_groups...]`` (R-LGP Eq. 1): the planar base in
the world frame, then the joints of the robot's groups in ``robot.toml`` order (HSR: arm, head,
gripper; PR2: torso, right arm, left arm, head, grippers). Mimic joints (HSR torso, finger
joints) follow their primary joint; every other URDF joint is locked at its home value.

Internally pinocchio sees the full tree; ``q_full = A @ q + b`` maps our ``q`` to it.
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from functools import cached_property

import numpy as np
import pinocchio as pin
from numpy.typing import ArrayLike, NDArray

from rlgp_exec.errors import ModelError
from rlgp_exec.robot.config import BASE_JOINTS, Manipulator, RobotConfig, load_robot_config
from rlgp_exec.robot.limits import JointLimits
from rlgp_exec.robot.urdf import PreparedUrdf, prepare_urdf

__all__ = ["RobotModel", "load_robot"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

_JERK_PER_ACC = 10.0  # default jerk limit = 10 x acceleration limit [1/s]
_CACHE: dict[str, RobotModel] = {}


class RobotModel:
    """Kinematics and limits of one robot. Build with :func:`load_robot`."""

    def __init__(self, config: RobotConfig) -> None:
        self.config = config
        self.name = config.name
        self.urdf: PreparedUrdf = prepare_urdf(config)
        try:
            self.pin_model = pin.buildModelFromXML(self.urdf.pinocchio_xml)
        except Exception as e:  # pinocchio raises plain RuntimeError/ValueError
            raise ModelError(f"{self.name}: pinocchio could not build the model: {e}") from e
        self.pin_data = self.pin_model.createData()

        names: list[str] = list(BASE_JOINTS)
        for group, joints in config.groups.items():
            for j in joints:
                if j in names:
                    raise ModelError(f"{self.name}: joint {j!r} appears in two groups (second: {group!r})")
                names.append(j)
        self.joint_names: tuple[str, ...] = tuple(names)
        self.nq = len(names)
        self._index = {n: i for i, n in enumerate(names)}
        self.groups: dict[str, tuple[int, ...]] = {"base": (0, 1, 2)}
        for group, joints in config.groups.items():
            self.groups[group] = tuple(self._index[j] for j in joints)
        self._build_map()
        self.limits = self._build_limits()
        log.debug("robot %s: %d joints in q, %d in the full tree", self.name, self.nq, self.pin_model.nq)

    # ------------------------------------------------------------------ configuration map
    def _build_map(self) -> None:
        m = self.pin_model
        if m.nq != m.nv:
            raise ModelError(f"{self.name}: expected nq == nv in the prepared model, got {m.nq} != {m.nv}")
        full_idx = {m.names[j]: m.joints[j].idx_q for j in range(1, m.njoints)}
        for n in self.joint_names:
            if n not in full_idx:
                raise ModelError(
                    f"{self.name}: group joint {n!r} is not a movable URDF joint; valid: {sorted(full_idx)}"
                )
        A = np.zeros((m.nq, self.nq))
        b = np.zeros(m.nq)
        for n, i in self._index.items():
            A[full_idx[n], i] = 1.0
        mimic_of = {mj.joint: mj for mj in self.urdf.mimics}
        self.locked: dict[str, float] = {}
        for jname, iq in full_idx.items():
            if jname in self._index:
                continue
            mj = mimic_of.get(jname)
            if mj is not None and mj.primary in self._index:
                A[iq, self._index[mj.primary]] = mj.multiplier
                b[iq] = mj.offset
            else:
                b[iq] = self.config.home.get(jname, 0.0)
                self.locked[jname] = b[iq]
        self.A, self.b = A, b
        self.A.setflags(write=False)
        self.b.setflags(write=False)

    def _build_limits(self) -> JointLimits:
        by_name = {j.name: j for j in self.urdf.joints}
        lo, hi, vel, acc, jerk, cont = [], [], [], [], [], []
        base = self.config.base
        for i, n in enumerate(self.joint_names):
            if i < 3:
                lo.append(-np.inf if i == 2 else -1e3)
                hi.append(np.inf if i == 2 else 1e3)
                vel.append(base.velocity[i])
                acc.append(base.acceleration[i])
                jerk.append(base.jerk[i])
                cont.append(i == 2)
                continue
            j = by_name[n]
            is_cont = j.type == "continuous"
            if not is_cont and (j.lower is None or j.upper is None):
                raise ModelError(f"{self.name}: joint {n!r} has no position limits in the URDF")
            lo.append(-np.inf if is_cont else float(j.lower))  # type: ignore[arg-type]
            hi.append(np.inf if is_cont else float(j.upper))  # type: ignore[arg-type]
            if j.velocity is None:
                raise ModelError(f"{self.name}: joint {n!r} has no velocity limit in the URDF")
            vel.append(j.velocity)
            if n not in self.config.acceleration:
                raise ModelError(f"{self.name}: robot.toml [acceleration] has no limit for {n!r}")
            a = self.config.acceleration[n]
            acc.append(a)
            jerk.append(self.config.jerk.get(n, _JERK_PER_ACC * a))
            cont.append(is_cont)
        return JointLimits(
            self.joint_names, np.array(lo), np.array(hi), np.array(vel), np.array(acc), np.array(jerk), np.array(cont)
        )

    # ------------------------------------------------------------------ names and vectors
    def index(self, joint: str) -> int:
        try:
            return self._index[joint]
        except KeyError:
            raise ModelError(f"{self.name}: unknown joint {joint!r}; valid: {list(self.joint_names)}") from None

    def group(self, name: str) -> tuple[int, ...]:
        """Indices into q of a group ("base", or a group of robot.toml)."""
        try:
            return self.groups[name]
        except KeyError:
            raise ModelError(f"{self.name}: unknown group {name!r}; valid: {list(self.groups)}") from None

    def manipulator(self, name: str | None = None) -> Manipulator:
        return self.config.manipulator(name)

    def home(self, base: Sequence[float] = (0.0, 0.0, 0.0), joints: Mapping[str, float] | None = None) -> FloatArray:
        """q (nq,) at the robot.toml home pose, the base at ``base`` = (x, y, yaw), with overrides."""
        q = np.zeros(self.nq)
        q[:3] = base
        for n, v in self.config.home.items():
            if n in self._index:
                q[self._index[n]] = v
        for n, v in (joints or {}).items():
            q[self.index(n)] = v
        return self.limits.wrap(q)

    def full_q(self, q: ArrayLike) -> FloatArray:
        """The pinocchio configuration (nq_full,) of ``q`` (nq,)."""
        x = np.asarray(q, dtype=float)
        if x.shape != (self.nq,):
            raise ModelError(f"{self.name}: q must have shape ({self.nq},), got {x.shape}")
        return self.A @ x + self.b

    def random_q(self, rng: np.random.Generator, base_box: float = 2.0) -> FloatArray:
        """A uniformly random q within limits; base x, y in [-base_box, base_box], yaw in [-pi, pi)."""
        lo = np.where(np.isfinite(self.limits.lower), self.limits.lower, -np.pi)
        hi = np.where(np.isfinite(self.limits.upper), self.limits.upper, np.pi)
        lo[:2], hi[:2] = -base_box, base_box
        return rng.uniform(lo, hi)

    # ------------------------------------------------------------------ kinematics
    @cached_property
    def frame_names(self) -> tuple[str, ...]:
        return tuple(f.name for f in self.pin_model.frames)

    def frame_id(self, frame: str) -> int:
        if not self.pin_model.existFrame(frame):
            raise ModelError(f"{self.name}: unknown frame {frame!r}; e.g. {list(self.frame_names[-8:])}")
        return int(self.pin_model.getFrameId(frame))

    def fk(self, q: ArrayLike, frame: str) -> FloatArray:
        """T_world_frame (4, 4) at q."""
        return self.fk_many(q, [frame])[0]

    def fk_many(self, q: ArrayLike, frames: Sequence[str]) -> list[FloatArray]:
        """[T_world_frame (4, 4)] for each frame, one kinematics pass."""
        ids = [self.frame_id(f) for f in frames]
        pin.framesForwardKinematics(self.pin_model, self.pin_data, self.full_q(q))
        return [self.pin_data.oMf[i].homogeneous.copy() for i in ids]

    def jacobian(self, q: ArrayLike, frame: str) -> FloatArray:
        """Frame Jacobian (6, nq) w.r.t. q: rows [v; w] of the frame origin, world-aligned axes."""
        qf = self.full_q(q)
        fid = self.frame_id(frame)
        J = pin.computeFrameJacobian(self.pin_model, self.pin_data, qf, fid, pin.LOCAL_WORLD_ALIGNED)
        return np.asarray(J @ self.A)

    # ------------------------------------------------------------------ CasADi
    def casadi_fk(self, frames: Sequence[str]):  # -> casadi.Function
        """A CasADi function q (nq,) -> [T_world_frame (4, 4), ...], built from this model."""
        # local: robot.casadi_fk brings CasADi
        from rlgp_exec.robot.casadi_fk import build_casadi_fk

        return build_casadi_fk(self, tuple(frames))


def load_robot(name: str) -> RobotModel:
    """The RobotModel of "hsr" or "pr2" (built once per process, then shared: it is read-only)."""
    model = _CACHE.get(name)
    if model is None:
        model = RobotModel(load_robot_config(name))
        _CACHE[name] = model
    return model
