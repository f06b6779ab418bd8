"""Act, in the dry run: stream a trajectory to the simulated robot through the HAL and check it.

At 100 Hz a Ruckig :class:`~rlgp_exec.timing.Streamer` follows the trajectory; its setpoints go to
the HAL's sim backend as it would go to the HSR: arm and head joints as position setpoints with
feed-forward velocities, the base as a twist in the base frame (feed-forward plus a proportional
correction of the odometry error). The physics runs in lock-step. Every cycle the world is checked
for penetrations; at the end the hand's position is compared with the target.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from rlgp_exec.hal import make_backend
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene
from rlgp_exec.timing import Streamer, Trajectory

__all__ = ["ExecutionResult", "execute_on_sim"]

CONTROL_DT = 0.01  # [s] 100 Hz, the HSR controllers' rate
BASE_GAIN = 2.0  # [1/s] odometry error correction
TARGET_TOL = 0.03  # [m] the hand must end this close to the target


@dataclass(frozen=True)
class ExecutionResult:
    cycles: int
    duration_s: float
    tracking_err_max: float  # [rad or m] commanded vs measured joints
    hand_err: float  # [m] final hand position vs target
    collisions: tuple[str, ...]
    refused: int  # setpoints the HAL refused

    @property
    def ok(self) -> bool:
        return not self.collisions and self.hand_err <= TARGET_TOL and self.refused == 0

    def summary(self) -> str:
        head = (
            f"{self.cycles} cycles at 100 Hz ({self.duration_s:.2f} s simulated); hand {self.hand_err * 1e3:.0f} mm "
            f"from the target; max tracking error {self.tracking_err_max:.3f}; refused setpoints {self.refused}"
        )
        return head + (f"; COLLISIONS: {list(self.collisions)[:3]}" if self.collisions else "; no collisions")


def execute_on_sim(scene: Scene, trajectory: Trajectory, target: FloatArray, settle_s: float = 1.0) -> ExecutionResult:
    hal = make_backend("sim", scene=scene)
    hal.configure()
    hal.activate()
    try:
        sim = hal.sim  # type: ignore[attr-defined]
        model = hal.model
        streamer = Streamer(model.limits, CONTROL_DT, trajectory.sample(0.0)[0])
        streamer.follow(trajectory)
        names = list(hal.setpoint_names)
        idx = [model.index(n) for n in names]
        collisions: list[str] = []
        err_max, cycles, refused = 0.0, 0, 0
        n_max = int((trajectory.duration + 3 * streamer.lookahead + settle_s) / CONTROL_DT)
        for _ in range(n_max):
            sp = streamer.step()
            state = hal.read_state()
            x, y, yaw = state.base  # type: ignore[union-attr]
            q = sp.q_wrapped
            dx, dy, dyaw = sp.dq[0], sp.dq[1], sp.dq[2]
            ex, ey = q[0] - x, q[1] - y
            eyaw = math.remainder(q[2] - yaw, 2 * math.pi)
            c, s = math.cos(yaw), math.sin(yaw)
            vx_w, vy_w = dx + BASE_GAIN * ex, dy + BASE_GAIN * ey
            hal.write_base_velocity(c * vx_w + s * vy_w, -s * vx_w + c * vy_w, dyaw + BASE_GAIN * eyaw)
            if not hal.write_setpoint(q[idx], sp.dq[idx]):
                refused += 1
            hal.step(CONTROL_DT)  # type: ignore[attr-defined]
            cycles += 1
            meas = hal.read_state()
            qm = dict(zip(meas.names, meas.q, strict=True))  # type: ignore[union-attr]
            err_max = max(err_max, max(abs(qm[n] - q[i]) for n, i in zip(names, idx, strict=True) if n in qm))
            bad = sim.world.penetrations(tolerance=2e-3) if sim.world is not None else []
            collisions += [b for b in bad if b.startswith("robot")]
            if sp.finished and cycles * CONTROL_DT > trajectory.duration + settle_s:
                break
        q_meas = sim.measured_q()
        hand = model.fk(q_meas, model.manipulator().tool_frame)[:3, 3]
        return ExecutionResult(
            cycles,
            cycles * CONTROL_DT,
            err_max,
            float(np.linalg.norm(hand - target)),
            tuple(dict.fromkeys(collisions)),
            refused,
        )
    finally:
        hal.deactivate()
        hal.shutdown()
