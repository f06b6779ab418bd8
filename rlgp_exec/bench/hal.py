"""``rlgp-exec bench hal``: transport latency and rates of the HAL backends, measured on this machine.

* ``zenoh_rtt_us_p99``: round trip of a CDR JointTrajectory through two zenoh peer sessions on loopback
  (publish on one, echo back from the other), p99 over ``pings`` messages.
* ``state_rate_hz``: joint states received per second by a ZenohBackend from an in-process
  ZenohRobotServer publishing at 100 Hz (wall-clock, over ``seconds``).
* ``can_frames_per_s``: frames on the virtual CAN bus seen by a listener while the CanBackend runs its
  100 Hz SYNC cycle against the simulated node set and streams setpoints (a load, not a throughput limit).
* ``loop_period_err_ms_p99``: p99 |period - 10 ms| of a 100 Hz client control loop (sleep to absolute
  deadlines) that reads the state and writes a setpoint through the zenoh backend each cycle.
"""

from __future__ import annotations

import logging
import os
import platform
import socket
import threading
import time
import uuid
from typing import Any

import numpy as np
import zenoh

from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.types import JointSetpoint
from rlgp_exec.hal.zenoh_backend import ZenohBackend
from rlgp_exec.hal.zenoh_keys import session_config

__all__ = ["run_hal_bench"]

log = logging.getLogger(__name__)


def _port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _zenoh_rtt(pings: int) -> list[float]:
    ep = f"tcp/127.0.0.1:{_port()}"
    a = zenoh.open(session_config(listen=ep))
    b = zenoh.open(session_config(connect=ep))
    try:
        back = a.declare_publisher("bench/pong")
        b_pub = b.declare_publisher("bench/ping")
        a.declare_subscriber("bench/ping", lambda s: back.put(s.payload.to_bytes()))
        got = threading.Event()
        b.declare_subscriber("bench/pong", lambda s: got.set())
        payload = rc.encode_trajectory(JointSetpoint(("a", "b", "c", "d", "e"), np.zeros(5)), 0.01)
        time.sleep(0.5)  # let the subscriptions propagate
        rtt = []
        for _ in range(pings):
            got.clear()
            t0 = time.perf_counter()
            b_pub.put(payload)
            if got.wait(1.0):
                rtt.append((time.perf_counter() - t0) * 1e6)
        return rtt
    finally:
        b.close()
        a.close()


def _zenoh_loop(seconds: float) -> tuple[float, list[float]]:
    # local: hal.sim_physics brings PyBullet
    from rlgp_exec.hal.sim_physics import SimRobot

    # local: sim.robot_server brings matplotlib and SciPy
    from rlgp_exec.sim.robot_server import ZenohRobotServer

    ep = f"tcp/127.0.0.1:{_port()}"
    sim = SimRobot("hsr")
    server = ZenohRobotServer(sim, ep)
    server.start()
    hal = ZenohBackend("hsr", ep)
    try:
        hal.configure()
        if not hal.wait_for_robot(10.0):
            raise RuntimeError("bench: no state from the zenoh robot server")
        hal.activate()
        n0, t0 = hal.received, time.perf_counter()
        errs, period = [], 0.01
        nxt = last = time.perf_counter()
        while time.perf_counter() - t0 < seconds:
            st = hal.read_state()
            if st is not None:
                hal.write_setpoint(st.positions(hal.setpoint_names))
            nxt += period
            time.sleep(max(0.0, nxt - time.perf_counter()))
            now = time.perf_counter()
            errs.append(abs(now - last - period) * 1e3)
            last = now
        rate = (hal.received - n0) / (time.perf_counter() - t0)
        return rate, errs[1:]
    finally:
        hal.shutdown()
        server.stop()
        sim.close()


def _can_rate(seconds: float) -> float:
    # local: python-can (~0.3 s), canopen and PyBullet load only for the CAN bench
    import can

    from rlgp_exec.hal.can_backend import CanBackend
    from rlgp_exec.hal.sim_physics import SimRobot
    from rlgp_exec.sim.robot_server_can import CanRobotServer

    ch = f"bench-{uuid.uuid4().hex}"
    sim = SimRobot("hsr")
    server = CanRobotServer(sim, can.Bus(interface="virtual", channel=ch))
    server.start()
    hal = CanBackend("hsr", bus=can.Bus(interface="virtual", channel=ch))
    spy = can.Bus(interface="virtual", channel=ch)
    try:
        hal.configure()
        if not hal.wait_for_robot(10.0):
            raise RuntimeError("bench: the CAN node set does not answer")
        hal.activate()
        count, t0 = 0, time.perf_counter()
        nxt = t0
        while time.perf_counter() - t0 < seconds:
            st = hal.read_state()
            if st is not None:
                hal.write_setpoint(st.positions(hal.setpoint_names))
            while spy.recv(0.0) is not None:
                count += 1
            nxt += 0.01
            time.sleep(max(0.0, nxt - time.perf_counter()))
        return count / (time.perf_counter() - t0)
    finally:
        spy.shutdown()
        hal.shutdown()
        server.stop()
        sim.close()


def run_hal_bench(pings: int = 1000, seconds: float = 3.0) -> dict[str, Any]:
    log.info("zenoh: %d query round trips", pings)
    rtt = _zenoh_rtt(pings)
    log.info("zenoh: state stream and a 100 Hz loop for %.0f s", seconds)
    state_rate, loop_err = _zenoh_loop(seconds)
    log.info("can: frame rate over a virtual bus for %.0f s", seconds)
    can_rate = _can_rate(seconds)
    return {
        "task": "hal",
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "summary": {
            "zenoh_rtt_us_p99": float(np.percentile(rtt, 99)) if rtt else None,
            "zenoh_rtt_us_median": float(np.median(rtt)) if rtt else None,
            "zenoh_rtt_lost": pings - len(rtt),
            "state_rate_hz": state_rate,
            "can_frames_per_s": can_rate,
            "loop_period_err_ms_p99": float(np.percentile(loop_err, 99)) if loop_err else None,
        },
    }
