"""The e-stop is confirmed by the robot's reported state and sent again until it is, and a rearm is never
undone by a late re-send.

Zenoh: the HAL against an in-process ``ZenohRobotServer`` on a loopback port whose e-stop handler drops,
ignores or forgets e-stops. CAN: the simulated node set on python-can's virtual bus with a drive that
ignores quick stops. Deadlines are generous and every check polls: other test processes share the CPU.
"""

from __future__ import annotations

import threading
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field

import can
import pytest
from waiting import wait_for

from rlgp_exec.hal import EstopStatus, Lifecycle, make_backend
from rlgp_exec.hal import can_nodes as cn
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.can_backend import CanBackend
from rlgp_exec.hal.sim_physics import SimRobot
from rlgp_exec.hal.zenoh_backend import ESTOP_CONFIRM_S, KEEPALIVE_S, ZenohBackend
from rlgp_exec.sim.robot_process import free_endpoint
from rlgp_exec.sim.robot_server import ZenohRobotServer
from rlgp_exec.sim.robot_server_can import CanRobotServer

CONFIRM_WITHIN_S = 5.0  # [s] a re-sent e-stop takes ESTOP_CONFIRM_S + KEEPALIVE_S (0.4 s) unloaded
QUIET_S = 1.0  # [s] watched after a rearm for a late re-send: ten keepalive periods


@dataclass
class EstopWire:
    """The robot server's e-stop handler with a fault: e-stops that engage are dropped (the first
    ``drop`` of them, or all while ``ignore`` is set). ``seen`` is every e-stop that arrived, in order."""

    server: ZenohRobotServer
    drop: int = 0
    ignore: threading.Event = field(default_factory=threading.Event)
    seen: list[bool] = field(default_factory=list)
    dropped: int = 0

    def __post_init__(self) -> None:
        real = self.server._estop

        def handler(payload: bytes, topic: str) -> None:
            m = rc.decode(payload, "std_msgs/msg/Bool")
            engaged = not isinstance(m, rc.Rejected) and bool(m.data)
            self.seen.append(engaged)
            if engaged and (self.dropped < self.drop or self.ignore.is_set()):
                self.dropped += 1
                return
            real(payload, topic)

        self.server._estop = handler  # type: ignore[method-assign]  # before start(): the subscriber takes it


@contextmanager
def zenoh_rig(drop: int = 0, endpoint: str | None = None) -> Iterator[tuple[ZenohBackend, EstopWire, SimRobot]]:
    ep = endpoint or free_endpoint()
    sim = SimRobot("hsr")
    server = ZenohRobotServer(sim, ep)
    wire = EstopWire(server, drop=drop)
    server.start()
    hal = make_backend("zenoh", endpoint=ep)
    assert isinstance(hal, ZenohBackend)
    try:
        hal.configure()
        assert hal.wait_for_robot(15.0), "no state from the robot server"
        yield hal, wire, sim
    finally:
        hal.shutdown()
        server.stop()
        sim.close()


def _robot_estopped(hal: ZenohBackend) -> bool:
    st = hal.read_state()
    return st is not None and st.estopped


def test_zenoh_a_dropped_estop_is_sent_again_until_the_robot_reports_it():
    with zenoh_rig(drop=1) as (hal, wire, sim):
        t0 = time.monotonic()
        assert hal.estop().ok and hal.lifecycle is Lifecycle.ESTOPPED
        assert wait_for(lambda: sim.estopped, CONFIRM_WITHIN_S), f"never engaged; the robot saw {wire.seen}"
        took = time.monotonic() - t0
        assert wire.dropped == 1 and wire.seen[:2] == [True, True], wire.seen
        assert took >= ESTOP_CONFIRM_S, f"re-sent after {took:.2f} s, before the robot had its deadline"
        assert wait_for(lambda: hal.estop_status().confirmed, CONFIRM_WITHIN_S)
        status = hal.estop_status()
        assert status.engaged and status.resends >= 1, status
        n = len(wire.seen)  # confirmed: no more re-sends
        assert not wait_for(lambda: len(wire.seen) > n, QUIET_S), wire.seen
        assert hal.estop_status() == EstopStatus(True, True, status.resends)


def test_zenoh_a_robot_restarted_unstopped_is_estopped_again():
    ep = free_endpoint()
    with zenoh_rig(endpoint=ep) as (hal, wire, _sim):
        assert hal.estop().ok
        assert wait_for(lambda: hal.estop_status().confirmed, CONFIRM_WITHIN_S)
        assert hal.estop_status().resends == 0, "an e-stop that arrived was sent again"
        wire.server.stop()  # the robot server restarts and comes up un-stopped
        sim2 = SimRobot("hsr")
        server2 = ZenohRobotServer(sim2, ep)
        wire2 = EstopWire(server2)
        server2.start()
        try:
            assert wait_for(lambda: sim2.estopped, 20.0), f"the restarted robot is free; it saw {wire2.seen}"
            assert wire2.seen and all(wire2.seen), wire2.seen
            assert wait_for(lambda: hal.estop_status().confirmed, CONFIRM_WITHIN_S)
            assert hal.estop_status().resends >= 1
            assert _robot_estopped(hal)
        finally:
            server2.stop()
            sim2.close()


def test_zenoh_not_hearing_the_robot_keeps_resending():
    with zenoh_rig() as (hal, wire, sim):
        wire.ignore.set()  # the robot takes the e-stops and never reports one
        assert hal.estop().ok
        assert wait_for(lambda: hal.estop_status().resends >= 3, CONFIRM_WITHIN_S), hal.estop_status()
        assert not hal.estop_status().confirmed and not sim.estopped
        wire.ignore.clear()
        assert wait_for(lambda: hal.estop_status().confirmed, CONFIRM_WITHIN_S)
        assert sim.estopped


def test_zenoh_rearm_during_a_resend_stays_rearmed():
    """A re-send held up on its way out (a congested link) when the operator rearms: the release goes
    after it, and nothing engages the robot again."""
    with zenoh_rig() as (hal, wire, sim):
        wire.ignore.set()  # unconfirmed: the keepalive keeps re-sending
        in_resend = threading.Event()
        put = hal._put

        def slow_put(topic: str, payload: bytes) -> None:
            if topic == "estop" and threading.current_thread().name == "zenoh-keepalive":
                in_resend.set()
                time.sleep(0.2)
            put(topic, payload)

        hal._put = slow_put  # type: ignore[method-assign]
        assert hal.estop().ok
        assert in_resend.wait(CONFIRM_WITHIN_S), "no re-send of an unconfirmed e-stop"
        wire.ignore.clear()  # from here an e-stop that arrives engages the robot
        assert hal.rearm().ok and hal.lifecycle is Lifecycle.INACTIVE
        assert not hal.estop_status().engaged
        assert wait_for(lambda: False in wire.seen, CONFIRM_WITHIN_S), wire.seen
        release = wire.seen.index(False)
        # watched for a while: a late re-send would come within a period and engage the robot again
        assert not wait_for(lambda: sim.estopped or len(wire.seen) > release + 1, QUIET_S), wire.seen
        assert not _robot_estopped(hal) and wire.seen[-1] is False, wire.seen
        resends = hal.estop_status().resends
        assert resends >= 1
        assert not wait_for(lambda: hal.estop_status().resends > resends, 3 * KEEPALIVE_S)


# ------------------------------------------------------------------------------------------------- CAN
FLEX = 12  # arm_flex_joint's node


@contextmanager
def can_rig(ignore: set[int]) -> Iterator[tuple[CanBackend, CanRobotServer]]:
    """The HAL ACTIVE against the simulated drives; the drives in ``ignore`` drop quick stops."""
    ch = f"estop-{uuid.uuid4().hex}"
    sim = SimRobot("hsr")
    server = CanRobotServer(sim, can.Bus(interface="virtual", channel=ch))
    rpdo2 = server._rpdo2

    def lossy(d, data: bytes) -> None:  # type: ignore[no-untyped-def]
        v = cn.unpack("rpdo2", data)
        if v is not None and v[0] == cn.CW_QUICK_STOP and d.node.id in ignore:
            return
        rpdo2(d, data)

    server._rpdo2 = lossy  # type: ignore[method-assign]
    server.start()
    hal = make_backend("can", bus=can.Bus(interface="virtual", channel=ch), consumer_timeout_ms=2000)
    assert isinstance(hal, CanBackend)
    try:
        hal.configure()
        assert hal.wait_for_robot(10.0)
        hal.activate()
        yield hal, server
    finally:
        hal.shutdown()
        server.stop()
        sim.close()


def _drive(server: CanRobotServer, nid: int) -> str:
    with server.lock:
        return server.drives[nid].drive


def test_can_a_drive_that_missed_the_quick_stop_is_sent_it_again():
    ignore = {FLEX}
    with can_rig(ignore) as (hal, server):
        assert hal.estop().ok
        assert wait_for(lambda: hal.estop_status().resends >= 1, CONFIRM_WITHIN_S), hal.estop_status()
        assert _drive(server, FLEX) == "enabled" and not hal.estop_status().confirmed
        ignore.clear()
        assert wait_for(lambda: _drive(server, FLEX) == "quick_stop", CONFIRM_WITHIN_S)
        assert wait_for(lambda: hal.estop_status().confirmed, CONFIRM_WITHIN_S), hal.estop_status()


def test_can_rearm_during_a_resend_stays_rearmed():
    ignore = {FLEX}
    with can_rig(ignore) as (hal, server):
        in_resend = threading.Event()
        quick_stop = hal._quick_stop

        def slow_quick_stop(nid: int) -> None:
            if threading.current_thread().name == "can-supervisor":
                in_resend.set()
                time.sleep(0.1)
            quick_stop(nid)

        hal._quick_stop = slow_quick_stop  # type: ignore[method-assign]
        assert hal.estop().ok
        assert in_resend.wait(CONFIRM_WITHIN_S), "no re-send to the drive that ignored the quick stop"
        ignore.clear()
        assert hal.rearm().ok and not hal.estop_status().engaged
        assert wait_for(lambda: _drive(server, FLEX) == "switched_on", CONFIRM_WITHIN_S), _drive(server, FLEX)
        assert not wait_for(lambda: _drive(server, FLEX) != "switched_on", QUIET_S), _drive(server, FLEX)


if __name__ == "__main__":
    pytest.main([__file__, "-q"])
