"""``SimRobot``: the robot as PyBullet physics, stepped explicitly (lock-step), shared by the sim backend
and the simulated robot servers (zenoh, can).

* Arm, head and gripper joints: PyBullet position control towards the latest setpoint (mimic and
  locked joints through the RobotModel's joint map ``q_full = A q + b``), velocity-capped at the URDF
  limits, with the setpoint velocity as feed-forward.
* Base: the three planar joints (x, y, yaw) under velocity control; the commanded twist is in the
  base frame and expires after ``base_timeout`` s of sim time (a cmd_vel watchdog, as on the robot).
* Gripper: OPEN/CLOSE are position targets; GRASP closes with a force limit until a finger touches an
  object, then holds there and attaches the object to the palm with a fixed constraint, so a held
  object moves with the hand; OPEN releases it.
* E-stop: every joint holds where it is, the base stops, and new targets are ignored until rearm.

This module does not check commands: callers (the sim backend, the servers) validate first.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np
import pinocchio as pin
import pybullet as p
from numpy.typing import NDArray

from rlgp_exec.hal.types import GripperAction, GripperCommand, JointSetpoint, RobotState
from rlgp_exec.hal.validate import CommandLimits
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.limits import wrap_angle
from rlgp_exec.robot.pybullet_body import PyBulletRobot, pose_to_matrix
from rlgp_exec.scene import Scene

__all__ = ["SimRobot"]

log = logging.getLogger(__name__)
FloatArray = NDArray[np.float64]

_FINGER_LEVER = 0.1  # [m] grasp force -> hand motor torque
_DRAWER_FRICTION_N = 5.0  # [N] the drawer's slide friction
_JOINT_FORCE = 300.0  # [N|Nm] position-control force of the arm/head joints (beyond their gravity load)
_GRAVITY_MARGIN = 1.5  # the gravity load each motor may add, with this margin


def gravity_load(model, samples: int = 64, seed: int = 0) -> NDArray[np.float64]:
    """(nq_full,) the largest |gravity torque or force| [Nm | N] on each joint of the full tree over
    ``samples`` random configurations within the limits (pinocchio, from the URDF's inertias)."""
    pm = model.pin_model
    data = pm.createData()
    rng = np.random.default_rng(seed)
    worst = np.zeros(pm.nv)
    for _ in range(samples):
        tau = pin.computeGeneralizedGravity(pm, data, model.full_q(model.random_q(rng)))
        worst = np.maximum(worst, np.abs(tau))
    return worst


class SimRobot:
    """One robot (and optionally a scene) in its own PyBullet DIRECT client."""

    def __init__(
        self, robot: str = "hsr", scene: Scene | None = None, dt: float = 0.005, base_timeout: float = 0.5
    ) -> None:
        if scene is not None and scene.robot.name != robot:
            robot = scene.robot.name
        self.model = load_robot(robot)
        self.limits = CommandLimits(self.model)
        self.dt = float(dt)
        self.base_timeout = float(base_timeout)
        self.objects: dict[str, int] = {}
        self.cabinets: dict[str, tuple[int, int]] = {}  # name -> (body, drawer joint = drawer link)
        self.world = None
        if scene is not None:
            # local: world.pybullet_world brings OpenCV
            from rlgp_exec.world.pybullet_world import build_world

            self.world = build_world(scene, tags=False)
            self.client = self.world.client
            self.robot = self.world.robot
            self.objects = dict(self.world.objects)
            for name, cab in self.world.cabinets.items():
                self.cabinets[name] = (cab.body, cab.drawer_joint)
                # a free drawer with some friction, inside its travel: the hand on the knob moves it
                p.changeDynamics(cab.body, cab.drawer_joint, jointLowerLimit=0.0, jointUpperLimit=cab.travel,
                                 physicsClientId=self.client)
                p.setJointMotorControl2(cab.body, cab.drawer_joint, p.VELOCITY_CONTROL, targetVelocity=0.0,
                                        force=_DRAWER_FRICTION_N, physicsClientId=self.client)
        else:
            self.client = p.connect(p.DIRECT)
            p.setGravity(0, 0, -9.81, physicsClientId=self.client)
            col = p.createCollisionShape(p.GEOM_BOX, halfExtents=[20, 20, 0.05], physicsClientId=self.client)
            floor = p.createMultiBody(0.0, col, -1, [0, 0, -0.05], physicsClientId=self.client)
            self.robot = PyBulletRobot(self.model, self.client)
            self.robot.ignore_floor(floor)
        p.setPhysicsEngineParameter(fixedTimeStep=self.dt, physicsClientId=self.client)
        m, r = self.model, self.robot
        self._base_j = [r.joint_index[n] for n in m.joint_names[:3]]
        base_set = set(self._base_j)
        pm = m.pin_model
        full = [(r.joint_index[pm.names[j]], pm.joints[j].idx_q) for j in range(1, pm.njoints)]
        self._ctrl = [(ji, iq) for ji, iq in full if ji not in base_set]
        self._ctrl_idx = [ji for ji, _ in self._ctrl]
        self._ctrl_q = [iq for _, iq in self._ctrl]
        self._model_j = [r.joint_index[n] for n in m.joint_names]
        # the joint controllers carry the robot's weight (the HSR's gravity compensation, the PR2's torso
        # motor and arm counterbalance): each motor may add the largest gravity load it sees (the PR2's
        # torso lifts ~1200 N: with 300 N it sagged 14 cm below its setpoint over Zenoh)
        self._forces = _JOINT_FORCE + _GRAVITY_MARGIN * gravity_load(m)[self._ctrl_q]
        vel_full = np.full(m.pin_model.nq, 10.0)
        for i in range(m.nq):
            for iq in np.flatnonzero(m.A[:, i]):
                vel_full[iq] = m.limits.velocity[i] * max(1.0, abs(m.A[iq, i]))
        self._maxvel = vel_full[self._ctrl_q]
        self.manip = m.manipulator()
        self._grip_i = m.index(self.limits.gripper_joint)
        self._palm = r.link_index[self.manip.palm_frame]
        self._fingers = [r.link_index[n] for n in self.manip.links if n in r.link_index]
        self._fingers_set = set(self._fingers)
        self._grip_ctrl = {k for k, iq in enumerate(self._ctrl_q) if m.A[iq, self._grip_i] != 0.0}
        self.time = 0.0
        self.estopped = False
        self.faults: list[str] = []
        self._grasping = False
        self._grasp_force = 0.0
        self.held: str | None = None
        self.knob: str | None = None  # the cabinet whose knob the hand holds
        self._constraint: int | None = None
        self._base_cmd = np.zeros(3)
        self._base_cmd_t = -math.inf
        self._q_target = self._physical_q()  # motor targets, continuous joints unwrapped
        self._dq_target = np.zeros(m.nq)
        self.last_step_wall = time.monotonic()
        self._apply()

    # ------------------------------------------------------------------ commands (pre-validated)
    def set_joint_targets(self, sp: JointSetpoint) -> bool:
        """Position/velocity targets for some joints; False (ignored) while e-stopped."""
        if self.estopped:
            return False
        continuous = self.model.limits.continuous
        q_now = None
        for n, q, dq in zip(sp.names, sp.q, sp.dq, strict=True):
            i = self.model.index(n)
            if continuous[i]:
                # its target comes wrapped to [-pi, pi): the motor goes the short way from where the
                # joint physically is (3.11 after -3.08 is 0.05 rad on, not a turn back)
                q_now = self._physical_q() if q_now is None else q_now
                q = q_now[i] + wrap_angle(q - q_now[i])
            self._q_target[i] = q
            self._dq_target[i] = dq
        return True

    def set_base_velocity(self, vx: float, vy: float, wz: float) -> bool:
        if self.estopped:
            return False
        self._base_cmd = np.array([vx, vy, wz], dtype=float)
        self._base_cmd_t = self.time
        return True

    def gripper(self, cmd: GripperCommand) -> bool:
        if self.estopped:
            return False
        if cmd.action is GripperAction.GRASP:
            if self.held is None and self.knob is None:
                self._grasping = True
                self._grasp_force = cmd.force
                self._q_target[self._grip_i] = self.manip.closed
            self._dq_target[self._grip_i] = 0.0
            return True
        return self.gripper_to(self.manip.open if cmd.action is GripperAction.OPEN else self.manip.closed)

    def gripper_to(self, position: float) -> bool:
        """Position-control the gripper joint (releases a held object)."""
        if self.estopped:
            return False
        self._release()
        self._grasping = False
        self._q_target[self._grip_i] = position
        self._dq_target[self._grip_i] = 0.0
        return True

    def estop(self, engaged: bool) -> None:
        if engaged and not self.estopped:
            self._q_target = self._physical_q()  # hold here (base entries are unused: velocity control)
            self._dq_target[:] = 0.0
            self._grasping = False
        if engaged:
            self._base_cmd[:] = 0.0
        self.estopped = engaged

    # ------------------------------------------------------------------ physics
    def step(self, duration: float | None = None) -> None:
        """Advance the physics by ``duration`` [s] (default one step of ``dt``)."""
        n = 1 if duration is None else max(1, round(duration / self.dt))
        for _ in range(n):
            self._apply()
            p.stepSimulation(physicsClientId=self.client)
            self.time += self.dt
            if self._grasping:
                self._check_grasp()
        self.last_step_wall = time.monotonic()

    def _apply(self) -> None:
        m, cid, rid = self.model, self.client, self.robot.id
        # base: world-frame velocities of the planar joints from the base-frame twist
        yaw = p.getJointState(rid, self._base_j[2], physicsClientId=cid)[0]
        live = (self.time - self._base_cmd_t) <= self.base_timeout and not self.estopped
        cmd = self._base_cmd if live else np.zeros(3)
        c, s = math.cos(yaw), math.sin(yaw)
        v_world = [c * cmd[0] - s * cmd[1], s * cmd[0] + c * cmd[1], cmd[2]]
        p.setJointMotorControlArray(
            rid, self._base_j, p.VELOCITY_CONTROL, targetVelocities=v_world, forces=[1e4] * 3, physicsClientId=cid
        )
        qf = m.A @ self._q_target + m.b
        dqf = m.A @ self._dq_target
        forces = self._forces.copy()
        if self._grasping or self.held is not None:
            for k in self._grip_ctrl:
                forces[k] = max(self._grasp_force, 1.0) * _FINGER_LEVER
        for k, (ji, iq) in enumerate(self._ctrl):
            p.setJointMotorControl2(
                rid,
                ji,
                p.POSITION_CONTROL,
                targetPosition=float(qf[iq]),
                targetVelocity=float(dqf[iq]),
                force=float(forces[k]),
                maxVelocity=float(self._maxvel[k]),
                positionGain=0.3,
                velocityGain=1.0,
                physicsClientId=cid,
            )

    def _check_grasp(self) -> None:
        for body_name, body in self.objects.items():
            pts = p.getContactPoints(bodyA=self.robot.id, bodyB=body, physicsClientId=self.client)
            if any(c[3] in self._fingers_set for c in pts):
                self._attach(body_name, body)
                return
        for cab_name, (body, link) in self.cabinets.items():
            pts = p.getContactPoints(bodyA=self.robot.id, bodyB=body, linkIndexB=link, physicsClientId=self.client)
            if any(c[3] in self._fingers_set for c in pts):
                self._attach(cab_name, body, link)
                return
        q = p.getJointState(self.robot.id, self._model_j[self._grip_i], physicsClientId=self.client)[0]
        if q <= self.manip.closed + 0.02:
            self._grasping = False  # closed on nothing
            log.info("sim: grasp closed on nothing")

    def _attach(self, name: str, body: int, link: int = -1) -> None:
        """Hold ``body`` (its ``link``: a cabinet's drawer for a knob grasp) fixed to the palm."""
        cid, rid = self.client, self.robot.id
        # a constraint's frames are relative to the links' centres of mass (inertial frames), not their URDF
        # frames: the PR2's palm has its centre of mass 6.6 cm out along the tool axis, and a frame taken
        # from the URDF pose pulled every held block that far down the fingers (it slid until the fingertips
        # pinched its top, then hung 6.6 cm below the planned grasp and once swept a standing block away)
        palm_pos, palm_orn = p.getLinkState(rid, self._palm, physicsClientId=cid)[0:2]
        if link < 0:  # a base's pose is its inertial frame's
            pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=cid)
        else:
            pos, orn = p.getLinkState(body, link, physicsClientId=cid)[0:2]
        inv_pos, inv_orn = p.invertTransform(palm_pos, palm_orn)
        rel_pos, rel_orn = p.multiplyTransforms(inv_pos, inv_orn, pos, orn)
        self._constraint = p.createConstraint(
            rid,
            self._palm,
            body,
            link,
            p.JOINT_FIXED,
            [0, 0, 0],
            rel_pos,
            [0, 0, 0],
            parentFrameOrientation=rel_orn,
            physicsClientId=cid,
        )
        p.changeConstraint(self._constraint, maxForce=500.0, physicsClientId=cid)
        self._set_collisions(body, link, False)
        q = p.getJointState(rid, self._model_j[self._grip_i], physicsClientId=cid)[0]
        self._q_target[self._grip_i] = q  # hold the fingers where they touched
        self._grasping = False
        if link < 0:
            self.held = name
        else:
            self.knob = name
        log.info("sim: grasped %s%s at %s = %.3f", name, " (knob)" if link >= 0 else "", self.limits.gripper_joint, q)

    def _set_collisions(self, body: int, link: int, enabled: bool) -> None:
        cid, rid = self.client, self.robot.id
        for rl in range(-1, p.getNumJoints(rid, physicsClientId=cid)):
            p.setCollisionFilterPair(rid, body, rl, link, int(enabled), physicsClientId=cid)
        if link < 0:
            self.robot.ignore_body(body, not enabled)

    def _release(self) -> None:
        if self._constraint is None:
            return
        p.removeConstraint(self._constraint, physicsClientId=self.client)
        if self.held is not None:
            self._set_collisions(self.objects[self.held], -1, True)
            log.info("sim: released %s", self.held)
        elif self.knob is not None:
            body, link = self.cabinets[self.knob]
            self._set_collisions(body, link, True)
            log.info("sim: let go of the knob of %s", self.knob)
        self._constraint, self.held, self.knob = None, None, None

    def drawer_pose(self, cabinet: str) -> FloatArray:
        """T_world_drawer (4, 4) of a cabinet's drawer link."""
        body, link = self.cabinets[cabinet]
        pos, orn = p.getLinkState(body, link, physicsClientId=self.client)[4:6]
        return pose_to_matrix(pos, orn)

    # ------------------------------------------------------------------ state
    def _physical_q(self) -> FloatArray:
        """Joint positions as PyBullet integrates them (continuous joints not wrapped), (nq,)."""
        st = p.getJointStates(self.robot.id, self._model_j, physicsClientId=self.client)
        return np.array([s[0] for s in st])

    def measured_q(self) -> FloatArray:
        """Joint positions (nq,), continuous joints wrapped to [-pi, pi)."""
        return self.model.limits.wrap(self._physical_q())

    def state(self) -> RobotState:
        st = p.getJointStates(self.robot.id, self._model_j, physicsClientId=self.client)
        q = self.model.limits.wrap(np.array([s[0] for s in st]))
        dq = np.array([s[1] for s in st])
        c, s = math.cos(q[2]), math.sin(q[2])
        vb = (c * dq[0] + s * dq[1], -s * dq[0] + c * dq[1], dq[2])
        return RobotState(
            stamp=self.time,
            names=self.limits.names,
            q=q[3:],
            dq=dq[3:],
            base=(q[0], q[1], q[2]),
            base_velocity=vb,
            gripper=float(q[self._grip_i]),
            estopped=self.estopped,
            faults=tuple(self.faults),
        )

    def push_object(self, name: str, dx: float, dy: float) -> None:
        """Move a (not held) object by (dx, dy) [m] in the world frame, at rest."""
        body = self.objects[name]
        pos, orn = p.getBasePositionAndOrientation(body, physicsClientId=self.client)
        p.resetBasePositionAndOrientation(body, [pos[0] + dx, pos[1] + dy, pos[2]], orn, physicsClientId=self.client)
        p.resetBaseVelocity(body, [0, 0, 0], [0, 0, 0], physicsClientId=self.client)

    def object_pose(self, name: str) -> FloatArray:
        pos, orn = p.getBasePositionAndOrientation(self.objects[name], physicsClientId=self.client)
        return pose_to_matrix(pos, orn)

    def close(self) -> None:
        if self.world is not None:
            self.world.close()
        elif p.isConnected(self.client):
            p.disconnect(self.client)
