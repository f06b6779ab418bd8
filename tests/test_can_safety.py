"""The CAN HAL against frames from another master on the bus: NMT changes, heartbeat objects re-written,
rogue enables after the e-stop, EMCY resets, and a bounded fuzz run of all of them with random frames.

Each test runs the simulated node set (sim/robot_server_can.py) and the HAL on a python-can ``virtual`` bus,
plus a third bus, the rogue, that injects frames. Ground truth is read from the simulated drives.
"""

from __future__ import annotations

import logging
import random
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

import can
import numpy as np
import pytest
from waiting import wait_for

from rlgp_exec.hal import CommandStatus, HalError, Lifecycle, RobotState, make_backend
from rlgp_exec.hal import can_nodes as cn
from rlgp_exec.hal.can_backend import CanBackend, NodeHealth
from rlgp_exec.hal.sim_physics import SimRobot
from rlgp_exec.sim.robot_server_can import CanRobotServer

log = logging.getLogger(__name__)

FLEX = 12  # arm_flex_joint's node
NODES = (11, 12, 13, 14, 15, 16, 17, 18, 20)
STILL = 5e-3  # [m|rad] a joint this close to where it was has not moved
STOPPED = {"quick_stop", "fault"}
FUZZ_SEED, FUZZ_CASES = 20261201, 90  # cases per phase (ACTIVE, e-stopped)
# [rad] an impersonated enable moves a joint until the HAL quick-stops it again: 12 mrad (one 10 ms control
# period at arm_flex_joint's 1.2 rad/s) when the HAL reacts at once; eight periods leave a loaded machine
# room and still fail a joint that keeps going to the rogue's target 2 rad away
BURST = 0.1


@dataclass
class Rig:
    sim: SimRobot
    server: CanRobotServer
    hal: CanBackend
    rogue: can.BusABC

    def send(self, cob: int, data: bytes) -> None:
        self.rogue.send(can.Message(arbitration_id=cob, data=data, is_extended_id=False))

    def q(self) -> np.ndarray:
        with self.server.lock:
            return self.sim.state().q.copy()

    def drive_states(self) -> dict[int, str]:
        with self.server.lock:
            return {n: d.drive for n, d in self.server.drives.items()}

    def armed(self) -> bool:
        """Every drive OPERATIONAL with the HAL's heartbeat objects: its watchdog on the master is on."""
        hb, consumer = self.hal.heartbeat_objects
        with self.server.lock:
            return all(
                d.nmt == "OPERATIONAL" and d.hb_ms == hb and d.consumer == consumer for d in self.server.drives.values()
            )

    def followers(self) -> list[int]:
        """The drives that would follow a setpoint: enabled and OPERATIONAL."""
        with self.server.lock:
            return [n for n, d in self.server.drives.items() if d.drive == "enabled" and d.nmt == "OPERATIONAL"]

    def settled(self) -> bool:
        """The HAL faulted, or it trusts every node again."""
        return self.hal.lifecycle is Lifecycle.ERROR or (
            self.hal.heartbeat_ok() and all(s.health is NodeHealth.OK for s in self.hal.node_status())
        )

    def rogue_enable(self, nid: int, target: int, disable_voltage: bool = True) -> None:
        """What another master sends to move a drive: every drive out of Fault (and quick stop), ``nid``
        enabled, a setpoint and a SYNC to apply it."""
        for n in NODES:
            self.send(0x300 + n, cn.pack("rpdo2", cn.CW_FAULT_RESET, 0, 0))
            if disable_voltage:
                self.send(0x300 + n, cn.pack("rpdo2", cn.CW_DISABLE_VOLTAGE, 0, 0))
        self.send(0x300 + nid, cn.pack("rpdo2", cn.CW_ENABLE, cn.MODE_POSITION, 0))
        self.send(0x200 + nid, cn.pack("rpdo1_joint", target, 0))
        self.send(0x080, b"")


@contextmanager
def rig(consumer_timeout_ms: int = 500, echo: bool = False, **hal_options: object) -> Iterator[Rig]:
    """The rig, the HAL ACTIVE; ``echo``: the HAL's bus hands it its own frames back. The drives' watchdog
    on the master at 500 ms, not can_nodes.toml's 100: a loaded machine's scheduling gaps would fault them
    mid-test."""
    ch = f"safety-{uuid.uuid4().hex}"
    sim = SimRobot("hsr")
    server = CanRobotServer(sim, can.Bus(interface="virtual", channel=ch))
    server.start()
    bus = can.Bus(interface="virtual", channel=ch, receive_own_messages=echo)
    hal = make_backend("can", bus=bus, consumer_timeout_ms=consumer_timeout_ms, **hal_options)
    assert isinstance(hal, CanBackend)
    rogue = can.Bus(interface="virtual", channel=ch)
    try:
        hal.configure()
        assert hal.wait_for_robot(10.0)
        hal.activate()
        yield Rig(sim, server, hal, rogue)
    finally:
        rogue.shutdown()
        hal.shutdown()
        server.stop()
        sim.close()


def _estop(r: Rig) -> np.ndarray:
    assert r.hal.estop().ok
    assert wait_for(lambda: set(r.drive_states().values()) == {"quick_stop"}), r.drive_states()
    time.sleep(0.05)
    return r.q()


def _all_reinitialised(r: Rig) -> bool:
    return all(s.reinits for s in r.hal.node_status())


def _all_quick_stopped(r: Rig) -> bool:
    return set(r.drive_states().values()) == {"quick_stop"}


def _state(r: Rig) -> RobotState:
    st = r.hal.read_state()
    assert st is not None
    return st


def _moves(r: Rig, joint: str = "arm_flex_joint", by: float = -0.2) -> bool:
    """The HAL still commands the robot: a setpoint is accepted and the joint gets there."""
    hal = r.hal
    st = hal.read_state()
    assert st is not None
    q = st.positions(hal.setpoint_names)
    i = hal.setpoint_names.index(joint)
    q[i] += by
    res = hal.write_setpoint(q)
    assert res.ok, res
    k = hal.joint_names.index(joint)
    return wait_for(lambda: abs(r.q()[k] - q[i]) < 0.01, 5.0)


# ---------------------------------------------------------------------------------------------- NMT
@pytest.mark.parametrize(
    "frame",
    [
        pytest.param((0x000, bytes([0x02, FLEX])), id="nmt-stop"),
        pytest.param((0x000, bytes([0x80, 0])), id="nmt-pre-operational-all"),
        pytest.param((0x000, bytes([0x81, 0])), id="nmt-reset-node-all"),
        pytest.param((0x000, bytes([0x82, FLEX])), id="nmt-reset-comm"),
        pytest.param((0x600 + FLEX, bytes([0x23, 0x16, 0x10, 0x01, 0, 0, 0, 0])), id="sdo-0x1016-zero"),
        pytest.param((0x600 + FLEX, bytes([0x2B, 0x17, 0x10, 0x00, 0, 0, 0, 0])), id="sdo-0x1017-zero"),
    ],
)
def test_another_master_cannot_leave_a_drive_unwatched_or_the_hal_stale(frame, caplog):
    """After NMT stop / pre-operational / reset or a consumer heartbeat written to 0, the HAL notices,
    re-initialises the nodes and commands the robot again; the drives' watchdog on the master is back on
    (it faults them when the master goes silent)."""
    caplog.set_level(logging.WARNING, logger="rlgp_exec.hal.can_backend")
    with rig() as r:
        r.send(*frame)
        assert wait_for(lambda: any(s.reinits for s in r.hal.node_status()) and r.settled() and r.armed(), 5.0), (
            r.hal.node_status(),
            r.hal.fault_reason,
        )
        assert r.hal.lifecycle is Lifecycle.ACTIVE, r.hal.fault_reason
        assert "re-initialising" in caplog.text
        assert _moves(r)
        assert set(r.drive_states().values()) == {"enabled"}
        r.hal._periodic.stop()  # the master's heartbeat stops: the watchdog must trip
        assert wait_for(lambda: set(r.drive_states().values()) == {"fault"}, 2.0), r.drive_states()


def test_a_drive_disabled_by_another_master_is_enabled_again():
    with rig(consumer_timeout_ms=2000) as r:
        r.send(0x300 + FLEX, cn.pack("rpdo2", cn.CW_DISABLE_VOLTAGE, 0, 0))
        assert wait_for(lambda: r.drive_states()[FLEX] == "switched_on", 1.0)
        assert wait_for(lambda: r.drive_states()[FLEX] == "enabled", 2.0)
        assert r.hal.foreign.counts() == {"foreign_rpdo2": 1, "foreign_enable": 1}, r.hal.foreign.counts()
        assert _moves(r)


def test_a_node_that_cannot_be_reinitialised_faults_the_hal(monkeypatch):
    with rig(sdo_timeout=0.1) as r:
        sdo = r.server._sdo
        monkeypatch.setattr(r.server, "_sdo", lambda d, data: None if d.node.id == FLEX else sdo(d, data))
        r.send(0x000, bytes([0x02, FLEX]))  # stopped: it must be re-configured, and its SDO server is dead
        assert wait_for(lambda: r.hal.lifecycle is Lifecycle.ERROR, 5.0)
        assert f"node {FLEX} (arm_flex_joint)" in r.hal.fault_reason, r.hal.fault_reason
        assert not r.hal.heartbeat_ok()
        assert wait_for(lambda: not r.followers()), r.followers()
        assert r.sim.estopped


def test_configure_fails_on_a_node_that_does_not_keep_its_heartbeat_objects(monkeypatch):
    ch = f"safety-{uuid.uuid4().hex}"
    sim = SimRobot("hsr")
    server = CanRobotServer(sim, can.Bus(interface="virtual", channel=ch))
    sdo = server._sdo

    def forgetful(d, data: bytes) -> None:  # acknowledges the write of 0x1016:01, keeps 0
        sdo(d, data)
        if d.node.id == FLEX:
            d.consumer = 0

    monkeypatch.setattr(server, "_sdo", forgetful)
    server.start()
    hal = make_backend("can", bus=can.Bus(interface="virtual", channel=ch))
    try:
        with pytest.raises(HalError, match=rf"node {FLEX} \(arm_flex_joint\): heartbeat objects read back"):
            hal.configure()
        assert hal.lifecycle is Lifecycle.ERROR
    finally:
        hal.shutdown()
        server.stop()
        sim.close()


def test_a_heartbeat_switched_off_out_of_sight_is_switched_on_again():
    with rig() as r:
        with r.server.lock:
            r.server.drives[FLEX].hb_ms = 0
        assert wait_for(lambda: not r.hal.heartbeat_ok(), 2.0)
        assert wait_for(lambda: r.armed() and r.settled(), 3.0), r.hal.node_status()
        assert _moves(r)


def test_a_node_that_goes_silent_during_its_reinitialisation_is_taken_up_when_it_is_back():
    """Another master sends a node an SDO request, then the robot goes silent (its node set paused) for longer
    than the node's re-initialisation tries: no fault, stale meanwhile, and the node, in the same NMT state,
    re-initialised once it is back."""
    with rig(consumer_timeout_ms=2000, sdo_timeout=0.1) as r:  # the drives' watchdog outlasts the pause
        r.send(0x600 + FLEX, bytes([0x40, 0x41, 0x60, 0, 0, 0, 0, 0]))  # a read of the statusword
        time.sleep(0.02)
        r.server.paused = True
        time.sleep(0.8)
        assert r.hal.lifecycle is Lifecycle.ACTIVE and not r.hal.heartbeat_ok(), r.hal.fault_reason
        r.server.paused = False
        assert wait_for(lambda: r.settled() and r.armed() and r.hal.node_status()[1].reinits == 1, 5.0), (
            r.hal.node_status(),
            r.hal.fault_reason,
        )
        assert r.hal.lifecycle is Lifecycle.ACTIVE
        assert _moves(r)


def test_a_watchdog_disabled_out_of_sight_is_found_by_the_audit(caplog):
    """A change of 0x1016:01 that never crossed this bus segment (here: written inside the drive) is found
    by the periodic read-back and re-written."""
    caplog.set_level(logging.WARNING, logger="rlgp_exec.hal.can_backend")
    with rig(audit_period=0.2) as r:
        with r.server.lock:
            r.server.drives[FLEX].consumer = 0
        assert not r.armed()
        assert wait_for(r.armed, 3.0)
        assert f"node {FLEX} (arm_flex_joint): heartbeat objects 0x1017=20 ms, 0x1016:01=0x00000000" in caplog.text
        assert r.settled() and _moves(r)


def test_a_bus_that_echoes_our_frames_is_not_another_master():
    """With receive_own_messages (some adapters do the same) the HAL's own NMT, SDO and PDO frames come back
    to it: they start no re-initialisation and count as nothing foreign."""
    with rig(echo=True) as r:
        hal = r.hal
        assert _moves(r)
        _estop(r)
        assert hal.rearm().ok
        assert wait_for(lambda: not _state(r).estopped)
        hal.activate()
        assert _moves(r, by=0.1)
        assert hal.foreign.total == 0 and not any(s.reinits for s in hal.node_status()), hal.foreign.counts()
        r.send(0x000, bytes([0x02, FLEX]))  # one frame that is not ours: one node re-initialised, and no more
        assert wait_for(lambda: hal.node_status()[1].reinits == 1 and r.settled() and r.armed(), 5.0)
        time.sleep(0.3)
        assert [s.reinits for s in hal.node_status()] == [0, 1, 0, 0, 0, 0, 0, 0, 0]
        assert hal.foreign.total == 1, hal.foreign.counts()


# ---------------------------------------------------------------------------------------------- e-stop
def test_after_the_estop_only_rearm_enables_motion():
    """After the HAL's e-stop another master streams what moved the arm before: fault resets, enable, a
    setpoint far away and SYNC. The drives stay latched in quick stop: nothing moves. It then impersonates
    the HAL's rearm (disable voltage first), or resets and starts the nodes: the drives cannot tell, so
    that can move a joint until the HAL sees the frames and quick-stops it again (one control period
    at most in the simulation, ``BURST`` here); it cannot keep it moving, the e-stop stays latched and
    the HAL reports the enable. rearm() and activate() move the arm again."""
    with rig(consumer_timeout_ms=2000) as r:
        q0 = _estop(r)
        k = r.hal.joint_names.index("arm_flex_joint")
        end = time.monotonic() + 0.3
        while time.monotonic() < end:
            r.rogue_enable(FLEX, -2_000_000, disable_voltage=False)
            time.sleep(0.005)
        assert float(np.max(np.abs(r.q() - q0))) < STILL
        worst = 0.0
        for burst in range(6):
            before = r.q()
            if burst == 5:  # reset every node, then start them: the drives come up disabled
                r.send(0x000, bytes([0x81, 0]))
                r.send(0x000, bytes([0x01, 0]))
            r.rogue_enable(FLEX, -2_000_000)
            assert wait_for(
                lambda b=burst: (b < 5 or _all_reinitialised(r)) and r.settled() and _all_quick_stopped(r), 5.0
            ), (
                r.drive_states(),
                r.hal.node_status(),
            )
            time.sleep(0.05)
            worst = max(worst, float(np.max(np.abs(r.q() - before))))
        log.info("impersonating master after the e-stop: largest joint displacement per burst %.2e", worst)
        assert worst < BURST, worst
        assert r.hal.lifecycle is Lifecycle.ESTOPPED
        st = r.hal.read_state()
        assert st is not None and st.estopped
        assert r.hal.write_setpoint(st.positions(r.hal.setpoint_names)).status is CommandStatus.ESTOPPED
        assert r.hal.foreign.total > 0
        assert r.hal.rearm().ok
        assert wait_for(lambda: set(r.drive_states().values()) == {"switched_on"}), r.drive_states()
        assert wait_for(lambda: not _state(r).estopped)
        assert not any("e-stop was latched" in f for f in _state(r).faults), _state(r).faults
        r.hal.activate()
        assert _moves(r)
        assert abs(r.q()[k] - q0[k]) > 0.15


# ---------------------------------------------------------------------------------------------- EMCY
def test_an_emcy_reset_does_not_clear_a_fault_the_drive_still_reports():
    with rig() as r:
        r.hal._periodic.stop()
        assert wait_for(lambda: r.drive_states()[FLEX] == "fault", 2.0)

        def flex_faults() -> list[str]:
            st = r.hal.read_state()
            assert st is not None
            return [f for f in st.faults if f.startswith(f"node {FLEX} ")]

        assert wait_for(lambda: any("EMCY 0x8130" in f for f in flex_faults()))
        bc = r.hal.map.bus  # the master is back; the drive stays in Fault until a fault reset
        r.hal._periodic = r.hal.network.send_periodic(0x700 + bc.master_node_id, b"\x05", bc.master_heartbeat)
        r.send(0x080 + FLEX, bytes(8))  # EMCY 0x0000 from someone else
        time.sleep(0.1)  # ten statuswords
        assert r.drive_states()[FLEX] == "fault"
        faults = flex_faults()
        assert any("EMCY 0x8130" in f for f in faults) and any("statusword" in f for f in faults), faults
        st = r.hal.read_state()
        assert st is not None and st.estopped
        assert r.hal.estop().ok and r.hal.rearm().ok  # fault reset: the drive clears and says so by EMCY
        assert wait_for(lambda: flex_faults() == [] and not _state(r).estopped, 2.0), flex_faults()
        r.hal.activate()
        assert _moves(r)


# ---------------------------------------------------------------------------------------------- fuzz
def _tracks(r: Rig) -> bool:
    """The HAL's state is the robot's (within what a joint moves in a few SYNC periods): not stale."""
    st = r.hal.read_state()
    return st is not None and bool(np.allclose(st.q, r.q(), atol=0.05))


def _fuzz_case(rng: random.Random) -> tuple[str, list[tuple[int, bytes]]]:
    kind = rng.choice(("random", "nmt", "nmt", "sdo", "sdo", "emcy", "rpdo2", "rpdo1", "heartbeat", "impersonation"))
    return kind, _fuzz_frames(rng, kind)


def _fuzz_frames(rng: random.Random, kind: str) -> list[tuple[int, bytes]]:
    """One case: a few frames, random or crafted after the CANopen services our nodes use."""
    nid = rng.choice((*NODES, rng.randrange(1, 128)))
    if kind == "random":
        return [(rng.randrange(0x800), rng.randbytes(rng.randrange(9)))]
    if kind == "nmt":
        cmd = rng.choice((0x01, 0x02, 0x80, 0x81, 0x82, rng.randrange(256)))
        data = bytes([cmd, rng.choice((0, nid))])
        return [(0x000, data if rng.random() < 0.8 else data + rng.randbytes(rng.randrange(1, 7)))]
    if kind == "sdo":
        index, sub = rng.choice(((0x1016, 1), (0x1016, 1), (0x1017, 0), (0x6040, 0), (rng.randrange(0x10000), 0)))
        value = rng.choice((0, 0, rng.randrange(2**32)))
        cmd = rng.choice((0x23, 0x2B, 0x40, rng.randrange(256)))
        data = bytes([cmd]) + index.to_bytes(2, "little") + bytes([sub]) + value.to_bytes(4, "little")
        return [(0x600 + nid, data if rng.random() < 0.85 else data[: rng.randrange(8)])]
    if kind == "emcy":
        code = rng.choice((0x0000, 0x0000, cn.EMCY_HEARTBEAT, rng.randrange(0x10000)))
        data = code.to_bytes(2, "little") + rng.randbytes(6)
        return [(0x080 + nid, data if rng.random() < 0.8 else data[: rng.randrange(8)])]
    if kind == "rpdo2":
        cw = rng.choice(
            (cn.CW_ENABLE, cn.CW_QUICK_STOP, cn.CW_FAULT_RESET, cn.CW_DISABLE_VOLTAGE, rng.randrange(2**16))
        )
        data = cn.pack("rpdo2", cw, rng.choice((0, 1, 4, rng.randrange(-128, 128))), rng.randrange(2**16))
        return [(0x300 + nid, data if rng.random() < 0.85 else data[: rng.randrange(5)])]
    if kind == "rpdo1":
        return [(0x200 + nid, rng.randbytes(rng.choice((8, 8, 6, rng.randrange(9))))), (0x080, b"")]
    if kind == "heartbeat":
        return [(0x700 + nid, bytes([rng.choice((0x00, 0x04, 0x05, 0x7F, rng.randrange(256)))]))]
    frames = [(0x300 + n, cn.pack("rpdo2", cw, 0, 0)) for n in NODES for cw in (0x0080, 0x0000)]
    return [
        *frames,
        (0x300 + FLEX, cn.pack("rpdo2", cn.CW_ENABLE, 1, 0)),
        (0x200 + FLEX, cn.pack("rpdo1_joint", rng.randrange(-2_600_000, 0), 0)),
        (0x080, b""),
    ]


@pytest.mark.filterwarnings("error::pytest.PytestUnhandledThreadExceptionWarning")
def test_can_fuzz_no_crash_no_motion_while_estopped_never_stale():
    """Fixed seed, bounded: cases of random and crafted frames from another master while the HAL is ACTIVE,
    then while it is e-stopped. After each case: no handler failed, the HAL faulted or trusts every node
    again, and then every drive is OPERATIONAL with its watchdog on and the HAL's state is the robot's;
    while e-stopped nothing moved (a burst impersonating the HAL's rearm + enable: by less than ``BURST``)
    and every drive is back in quick stop. After each phase rearm() and activate() move the arm."""
    rng = random.Random(FUZZ_SEED)
    n_cases = FUZZ_CASES
    figures: Counter[str] = Counter()
    worst = {False: 0.0, True: 0.0}  # largest joint displacement in one case while e-stopped: impersonation?
    for phase in ("active", "estopped"):
        done = 0
        while done < n_cases:
            with rig(consumer_timeout_ms=2000) as r:  # a rebuilt rig after the HAL faults
                if phase == "estopped":
                    _estop(r)
                while done < n_cases:
                    kind, case = _fuzz_case(rng)
                    before = r.q()
                    done += 1
                    figures["cases"] += 1
                    figures["frames"] += len(case)
                    for cob, data in case:
                        r.send(cob, data)
                    time.sleep(0.03)  # three SYNCs: anything latched by a drive would be applied
                    assert wait_for(r.settled, 5.0), (case, r.hal.node_status())
                    if phase == "estopped":
                        moved = float(np.max(np.abs(r.q() - before)))
                        impersonation = kind == "impersonation"
                        worst[impersonation] = max(worst[impersonation], moved)
                        assert moved < (BURST if impersonation else STILL), (case, moved)
                        figures["impersonations" if impersonation else "other"] += 1
                        figures["impersonations_moved" if impersonation else "unsafe_motions"] += moved >= STILL
                    if r.hal.lifecycle is Lifecycle.ERROR:
                        figures["hal_faults"] += 1
                        log.info("fuzz: the HAL faulted after %s: %s", case, r.hal.fault_reason)
                        assert wait_for(lambda: not r.followers()), r.followers()
                        break
                    assert wait_for(r.armed, 2.0), (case, r.server.drives)
                    if phase == "estopped":
                        assert wait_for(lambda: set(r.drive_states().values()) <= STOPPED), (case, r.drive_states())
                    else:
                        assert wait_for(lambda: _tracks(r), 1.0), case
                    assert r.hal.rejects.counts().get("internal", 0) == 0, r.hal.rejects.last
                    assert r.server.rejects.counts().get("internal", 0) == 0, r.server.rejects.last
                figures["reinits"] += sum(s.reinits for s in r.hal.node_status())
                figures["foreign"] += r.hal.foreign.total
                if r.hal.lifecycle is not Lifecycle.ERROR:  # and the robot is the HAL's again
                    if r.hal.lifecycle is Lifecycle.ACTIVE:
                        _estop(r)
                    assert r.hal.rearm().ok
                    assert wait_for(lambda: not _state(r).estopped), _state(r).faults
                    r.hal.activate()
                    assert _moves(r, by=-0.2 if _state(r).position("arm_flex_joint") > -1.0 else 0.2)
    log.info(
        "CAN fuzz: %d cases (%d frames), 0 crashes; while e-stopped: %d/%d cases moved a joint >= %.0e (largest "
        "%.2e), %d/%d impersonated rearm + enable bursts did (largest %.2e, bound %.0e); %d node "
        "re-initialisations, %d HAL faults, %d frames from another master seen",
        figures["cases"],
        figures["frames"],
        figures["unsafe_motions"],
        figures["other"],
        STILL,
        worst[False],
        figures["impersonations_moved"],
        figures["impersonations"],
        worst[True],
        BURST,
        figures["reinits"],
        figures["hal_faults"],
        figures["foreign"],
    )
