"""HAL loopback: start the simulated HSR as a separate process (zenoh) and drive it through the HAL.

    .venv/bin/python tools/03_hal_loopback.py [--transport zenoh|can]

zenoh: ``python -m rlgp_exec.sim.robot_server`` runs in a subprocess (the real process and transport boundary);
can: the CANopen node set runs in a thread on python-can's virtual bus (it does not cross processes).
The script reads the state, streams a 1 s arm-lift ramp at 100 Hz, grasps the block of the grasp test
scene, lifts it, releases it, and exercises the e-stop. It prints what it sees.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.hal import GripperCommand, make_backend  # noqa: E402
from rlgp_exec.sim.robot_process import RobotProcess  # noqa: E402
from rlgp_exec.sim.robot_server_scene import grasp_scene, write_grasp_scene  # noqa: E402


def ramp(hal, joint: str, delta: float, seconds: float = 1.0) -> float:
    st = hal.read_state()
    q = st.positions(hal.setpoint_names)
    i = hal.setpoint_names.index(joint)
    q0, worst = q[i], 0.0
    for k in range(1, int(seconds * 100) + 1):
        q[i] = q0 + delta * k / (seconds * 100)
        hal.write_setpoint(q)
        time.sleep(0.01)
        worst = max(worst, abs(hal.read_state().position(joint) - q[i]))
    return worst


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--transport", choices=["zenoh", "can"], default="zenoh")
    args = ap.parse_args()
    cleanup = []
    if args.transport == "zenoh":
        scene = write_grasp_scene(Path(tempfile.mkdtemp()) / "grasp.toml")
        robot = RobotProcess(scene)
        ep = robot.endpoint
        print(robot.ready_line)
        cleanup.append(robot.stop)
        hal = make_backend("zenoh", endpoint=ep)
    else:
        import can

        from rlgp_exec.hal.sim_physics import SimRobot
        from rlgp_exec.sim.robot_server_can import CanRobotServer

        sim = SimRobot("hsr", grasp_scene())
        server = CanRobotServer(sim, can.Bus(interface="virtual", channel="loopback"))
        server.start()
        cleanup += [sim.close, server.stop]
        hal = make_backend("can", bus=can.Bus(interface="virtual", channel="loopback"))
    try:
        hal.configure()
        if not hal.wait_for_robot(15.0):
            print("no heartbeat from the robot", file=sys.stderr)
            return 1
        st = hal.read_state()
        print(f"state: {dict(zip(st.names, np.round(st.q, 3), strict=True))}, base {np.round(st.base, 3)}")
        hal.activate()
        print(f"hold 1 s: worst deviation {ramp(hal, 'arm_lift_joint', 0.0) * 1e3:.1f} mm")
        hal.gripper(GripperCommand.grasp(10.0))
        time.sleep(2.0)
        print(f"grasp: hand_motor_joint = {hal.read_state().gripper:.3f} rad (closed would be -0.6: block held)")
        print(f"lift with the block: worst tracking error {ramp(hal, 'arm_lift_joint', 0.05) * 1e3:.1f} mm")
        hal.gripper(GripperCommand.open())
        time.sleep(1.5)
        print(f"release: hand_motor_joint = {hal.read_state().gripper:.3f} rad")
        hal.estop()
        time.sleep(0.1)
        q = hal.read_state().positions(hal.setpoint_names)
        print(f"e-stop: robot reports estopped={hal.read_state().estopped}; setpoint -> {hal.write_setpoint(q).status}")
        hal.rearm()
        print(f"rejected payloads from the robot: {hal.rejects.counts()}; refused commands: {hal.refused.counts()}")
        return 0
    finally:
        hal.shutdown()
        for f in reversed(cleanup):
            f()


if __name__ == "__main__":
    sys.exit(main())
