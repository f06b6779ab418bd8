"""Act, in the dry run: execute a plan on the simulated robot through the HAL, and check the result.

Each phase of the plan is timed by TOPPRA (at the streamer's tracking headroom) and followed by a
100 Hz Ruckig :class:`~rlgp_exec.timing.Streamer`; setpoints go to the HAL's sim backend as they would
go to the HSR: arm and head joints as position setpoints with feed-forward velocities, the base as a
twist in the base frame (feed-forward plus a proportional correction of the odometry error). At the
end of a phase that grasps, the gripper closes with a force limit (the sim attaches the object when
the fingers stop on it); at the end of one that releases, it opens. The physics runs in lock-step.
Every cycle the world is checked for robot penetrations; at the end, the goal is checked on the
objects' simulated poses.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from rlgp_exec.hal import make_backend
from rlgp_exec.hal.types import GripperCommand
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.validate import goal_holds
from rlgp_exec.scene import Scene
from rlgp_exec.timing import TRACKING_HEADROOM, Streamer, time_parameterize

__all__ = ["ExecutionResult", "execute_plan"]

CONTROL_DT = 0.01  # [s] 100 Hz, the HSR controllers' rate
BASE_GAIN = 2.0  # [1/s] odometry error correction
GRIPPER_S = 1.5  # [s] allowed for the gripper to close or open


@dataclass(frozen=True)
class ExecutionResult:
    cycles: int
    duration_s: float
    tracking_err_max: float  # [rad or m] commanded vs measured joints
    collisions: tuple[str, ...]
    refused: int  # setpoints the HAL refused
    unmet: tuple[str, ...]  # goal literals that do not hold in the simulated end state
    timing_failures: tuple[str, ...]

    @property
    def ok(self) -> bool:
        return not (self.collisions or self.refused or self.unmet or self.timing_failures)

    def summary(self) -> str:
        s = (
            f"{self.cycles} cycles at 100 Hz ({self.duration_s:.1f} s simulated); max tracking error "
            f"{self.tracking_err_max:.3f}; refused setpoints {self.refused}; "
            f"{'no collisions' if not self.collisions else 'COLLISIONS: ' + str(list(self.collisions)[:3])}; "
            f"{'goal met in the simulation' if not self.unmet else 'goal NOT met: ' + '; '.join(self.unmet)}"
        )
        return s + (f"; timing failed: {self.timing_failures}" if self.timing_failures else "")


def execute_plan(scene: Scene, plan: Plan, settle_s: float = 0.5) -> ExecutionResult:
    hal = make_backend("sim", scene=scene)
    hal.configure()
    hal.activate()
    try:
        sim = hal.sim  # type: ignore[attr-defined]
        model = hal.model
        limits = model.limits.scaled(*TRACKING_HEADROOM)
        names = list(hal.setpoint_names)
        idx = [model.index(n) for n in names]
        streamer = Streamer(model.limits, CONTROL_DT, plan.phases[0].path[0])
        collisions: list[str] = []
        timing_failures: list[str] = []
        err_max, cycles, refused = 0.0, 0, 0

        def cycle() -> bool:
            """One control cycle; True when the streamer has finished what it was doing."""
            nonlocal err_max, cycles, refused
            sp = streamer.step()
            state = hal.read_state()
            x, y, yaw = state.base  # type: ignore[union-attr]
            q = sp.q_wrapped
            ex, ey, eyaw = q[0] - x, q[1] - y, math.remainder(q[2] - yaw, 2 * math.pi)
            vx, vy = sp.dq[0] + BASE_GAIN * ex, sp.dq[1] + BASE_GAIN * ey
            c, s = math.cos(yaw), math.sin(yaw)
            hal.write_base_velocity(c * vx + s * vy, -s * vx + c * vy, sp.dq[2] + BASE_GAIN * eyaw)
            if not hal.write_setpoint(q[idx], sp.dq[idx]):
                refused += 1
            hal.step(CONTROL_DT)  # type: ignore[attr-defined]
            cycles += 1
            meas = hal.read_state()
            qm = dict(zip(meas.names, meas.q, strict=True))  # type: ignore[union-attr]
            err_max = max(err_max, max(abs(qm[n] - q[i]) for n, i in zip(names, idx, strict=True) if n in qm))
            collisions.extend(
                b
                for b in (sim.world.penetrations(tolerance=3e-3) if sim.world else [])
                if b.startswith("robot") and not (sim.held and sim.held in b)
            )
            return sp.finished

        for k, ph in enumerate(plan.phases):
            if len(ph.path) > 1:
                res = time_parameterize(ph.path, limits)
                if not res.ok:
                    timing_failures.append(f"phase {k}: {res.status.value}: {res.reason}")
                    break
                streamer.follow(res.trajectory)  # type: ignore[arg-type]
                n_max = int((res.trajectory.duration + 3 * streamer.lookahead + settle_s) / CONTROL_DT)  # type: ignore[union-attr]
                for _ in range(n_max):
                    if cycle():
                        break
            if ph.grasp is not None or ph.release is not None:
                hal.gripper(GripperCommand.grasp(10.0) if ph.grasp is not None else GripperCommand.open())
                streamer.hold()
                for _ in range(int(GRIPPER_S / CONTROL_DT)):
                    cycle()
        poses = {name: sim.world.object_pose(name) for name in sim.world.objects} if sim.world else {}
        unmet = tuple(why for lit in scene.goal.literals for ok, why in [goal_holds(scene, lit, poses)] if not ok)
        return ExecutionResult(
            cycles,
            cycles * CONTROL_DT,
            err_max,
            tuple(dict.fromkeys(collisions)),
            refused,
            unmet,
            tuple(timing_failures),
        )
    finally:
        hal.deactivate()
        hal.shutdown()
