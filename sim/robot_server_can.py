"""The simulated CANopen node set: one node per drive of ``robots/<robot>/can_nodes.toml`` on a python-can
bus, backed by a :class:`SimRobot` stepped in real time.

Per node: NMT (boot-up, start/stop/pre-operational, reset node, reset communication: the latter clears
only the communication objects), an expedited SDO server for the heartbeat objects (0x1016:01, 0x1017) and
a few read-only objects (none of it in STOPPED), RPDO1 latched and applied at the next SYNC, RPDO2
(controlword, mode, grasp force) applied on reception, TPDOs sent on every SYNC, a heartbeat producer and a
consumer of the master's heartbeat (Fault + EMCY 0x8130 when it goes silent). The drive state machine is
the CiA 402 subset of can_nodes.toml, latched like a real drive's: quick stop is left only by disable
voltage (0x0000), Fault only by fault reset (0x0080) once its cause is gone, and enable (0x000F) is refused
in both; the drive cannot tell its master's frames from anyone else's.
Every frame that is malformed (wrong length, RTR, extended id, unknown NMT command, bad SDO request,
setpoint outside the joint limits) is rejected, counted and logged, and moves nothing.

python-can's ``virtual`` interface only connects buses inside one process: tests run this node set in
a thread of the test process. Across processes use ``socketcan`` (vcan0) or ``udp_multicast``.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from collections import Counter
from typing import Any

import can
import numpy as np

from rlgp_exec.hal import can_nodes as cn
from rlgp_exec.hal.can_nodes import CanMap, CanNode, load_can_map, pack, unpack
from rlgp_exec.hal.sim_physics import SimRobot
from rlgp_exec.hal.types import GripperCommand, JointSetpoint
from rlgp_exec.hal.validate import CommandLimits, RejectCounter
from rlgp_exec.sim.realtime import RealTimeLoop

__all__ = ["CanRobotServer", "open_bus"]

log = logging.getLogger("rlgp_exec.sim.robot_server_can")

NMT_STATE = {"PRE-OPERATIONAL": 0x7F, "OPERATIONAL": 0x05, "STOPPED": 0x04}
NMT_CMD = {0x01: "OPERATIONAL", 0x02: "STOPPED", 0x80: "PRE-OPERATIONAL", 0x81: "RESET", 0x82: "RESET_COMM"}
SDO_ABORT_NO_OBJECT, SDO_ABORT_BAD_CMD, SDO_ABORT_RANGE = 0x06020000, 0x05040001, 0x06090030


def open_bus(interface: str, channel: str) -> can.BusABC:
    return can.Bus(interface=interface, channel=channel)


class _Drive:
    def __init__(self, node: CanNode) -> None:
        self.node = node
        self.nmt = "PRE-OPERATIONAL"
        self.drive = "switched_on"  # | "enabled" | "quick_stop" | "fault"
        self.pending: tuple[int, ...] | None = None  # latched RPDO1
        self.mode = cn.MODE_POSITION
        self.hb_ms = 0  # 0x1017
        self.consumer = 0  # 0x1016:01
        self.fault_code = 0  # the error code of a Fault
        self.last_hb_sent = 0.0

    def fault(self, code: int) -> None:
        self.drive, self.fault_code, self.pending = "fault", code, None

    def statusword(self) -> int:
        sw = 0x3  # ready to switch on, switched on
        if self.drive == "enabled":
            sw |= cn.SW_ENABLED
        if self.drive == "fault":
            sw |= cn.SW_FAULT
        if self.drive != "quick_stop":
            sw |= cn.SW_NOT_QUICK_STOP
        return sw


class CanRobotServer:
    """The robot side of the can backend, driving a :class:`SimRobot`."""

    def __init__(
        self,
        sim: SimRobot,
        bus: can.BusABC,
        rate_hz: float = 100.0,
        can_map: CanMap | None = None,
        realtime: bool = False,
    ) -> None:
        self.sim = sim
        self.bus = bus
        self.map = can_map or load_can_map(sim.model)
        self.limits = CommandLimits(sim.model)
        self.drives = {n.id: _Drive(n) for n in self.map.nodes}
        self.rejects = RejectCounter("robot_server[can]")
        self.accepted: Counter[str] = Counter()
        self.ignored = 0  # frames for other nodes (not errors)
        self.lock = threading.RLock()
        self.period = 1.0 / rate_hz
        self.loop = RealTimeLoop(self.period, self.tick, "can-robot", realtime)
        self._notifier: can.Notifier | None = None
        self._master_hb = time.monotonic()
        self.paused = False  # tests: a powered-off robot (no frames out, none processed)

    # ------------------------------------------------------------------ set-up
    def start(self) -> None:
        self._notifier = can.Notifier(self.bus, [self._on_frame], timeout=0.05)
        for d in self.drives.values():
            self._send(0x700 + d.node.id, b"\x00")  # boot-up
        self.loop.start()
        log.info("CAN robot server (%s): %d nodes on %s", self.sim.model.name, len(self.drives), self.bus.channel_info)

    def stop(self) -> None:
        self.loop.stop()
        if self._notifier is not None:
            self._notifier.stop()
        self.bus.shutdown()

    def _send(self, cob_id: int, data: bytes) -> None:
        try:
            self.bus.send(can.Message(arbitration_id=cob_id, data=data, is_extended_id=False))
        except can.CanError as e:
            log.warning("CAN send 0x%X failed: %s", cob_id, e)

    def _reject(self, key: str, reason: str) -> None:
        self.rejects.reject(key, reason)

    # ------------------------------------------------------------------ physics + heartbeats
    def tick(self) -> None:
        if self.paused:
            return
        now = time.monotonic()
        with self.lock:
            self.sim.step(self.period)
            silent_ms = (now - self._master_hb) * 1e3
            for d in self.drives.values():
                if d.hb_ms and (now - d.last_hb_sent) * 1e3 >= d.hb_ms:
                    self._send(0x700 + d.node.id, bytes([NMT_STATE.get(d.nmt, 0x7F)]))
                    d.last_hb_sent = now
                if d.nmt == "OPERATIONAL" and d.drive == "enabled" and self._master_silent(d):
                    d.fault(cn.EMCY_HEARTBEAT)
                    self._send(0x80 + d.node.id, struct.pack("<HB5s", cn.EMCY_HEARTBEAT, 0x11, b""))
                    log.warning("node %d: master heartbeat lost (%.0f ms): fault", d.node.id, silent_ms)
            self._sync_estop()

    def _master_silent(self, d: _Drive) -> bool:
        timeout = d.consumer & 0xFFFF
        return bool(timeout) and (time.monotonic() - self._master_hb) * 1e3 > timeout

    def _sync_estop(self) -> None:
        stopped = any(d.drive in ("quick_stop", "fault") for d in self.drives.values())
        if stopped != self.sim.estopped:
            self.sim.estop(stopped)
        lost = "CAN: master heartbeat lost"
        if any(d.drive == "fault" and d.fault_code == cn.EMCY_HEARTBEAT for d in self.drives.values()):
            if lost not in self.sim.faults:
                self.sim.faults.append(lost)
        elif lost in self.sim.faults:
            self.sim.faults.remove(lost)

    # ------------------------------------------------------------------ frames
    def _on_frame(self, msg: can.Message) -> None:
        if self.paused:
            return
        try:
            with self.lock:
                self._dispatch(msg)
        except Exception as e:  # never let a frame kill the node set
            self._reject("internal", f"frame 0x{msg.arbitration_id:X}: {type(e).__name__}: {e}")
            log.exception("CAN node set: handler failed")

    def _dispatch(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self._reject("error_frame", "CAN error frame")
            return
        if msg.is_extended_id or msg.is_remote_frame or getattr(msg, "is_fd", False):
            self._reject("bad_frame", f"0x{msg.arbitration_id:X}: extended/RTR/FD frames are not used")
            return
        cob, data = msg.arbitration_id, bytes(msg.data)
        if cob == 0x000:
            self._nmt(data)
            return
        if cob == 0x080:
            if len(data) > 1:
                self._reject("bad_length", f"SYNC with {len(data)} bytes")
                return
            self._sync()
            return
        if cob == 0x700 + self.map.bus.master_node_id:
            if len(data) != 1:
                self._reject("bad_length", f"master heartbeat with {len(data)} bytes")
                return
            self._master_hb = time.monotonic()
            return
        fn, nid = cob & 0x780, cob & 0x7F
        d = self.drives.get(nid)
        if d is None or fn not in (0x200, 0x300, 0x600):
            self.ignored += 1
            return
        if fn == 0x600 and d.nmt == "STOPPED":
            self._reject("not_operational", f"node {nid}: SDO 0x{cob:X} while STOPPED")
        elif fn == 0x600:
            self._sdo(d, data)
        elif d.nmt != "OPERATIONAL":
            self._reject("not_operational", f"node {nid}: PDO 0x{cob:X} while {d.nmt}")
        elif fn == 0x200:
            self._rpdo1(d, data)
        else:
            self._rpdo2(d, data)

    def _nmt(self, data: bytes) -> None:
        if len(data) != 2 or data[0] not in NMT_CMD or data[1] not in (0, *self.drives):
            self._reject("bad_nmt", f"NMT frame {data.hex()}")
            return
        state = NMT_CMD[data[0]]
        for d in self.drives.values():
            if data[1] in (0, d.node.id):
                if state.startswith("RESET"):  # reset comm keeps the drive's state, reset node does not
                    d.nmt, d.pending, d.hb_ms, d.consumer = "PRE-OPERATIONAL", None, 0, 0
                    if state == "RESET":
                        d.drive, d.fault_code = "switched_on", 0
                    self._send(0x700 + d.node.id, b"\x00")
                else:
                    d.nmt = state
        self._sync_estop()
        self.accepted["nmt"] += 1

    def _rpdo1(self, d: _Drive, data: bytes) -> None:
        layout = "rpdo1_base" if d.node.is_base else "rpdo1_joint"
        v = unpack(layout, data)
        if v is None:
            self._reject("bad_length", f"node {d.node.id}: RPDO1 with {len(data)} bytes")
            return
        if d.node.is_base:
            reason = self.limits.check_base_velocity(v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3)
        else:
            sp = JointSetpoint((str(d.node.joint),), [v[0] * d.node.unit], [v[1] * d.node.unit])
            reason = self._check_joint(sp)
        if reason:
            self._reject("limits", f"node {d.node.id}: {reason}")
            self._send(0x80 + d.node.id, struct.pack("<HB5s", cn.EMCY_LIMITS, 0x01, b""))
            return
        d.pending = v  # applied at the next SYNC

    def _check_joint(self, sp: JointSetpoint) -> str:
        if sp.names[0] == self.limits.gripper_joint:
            i = self.limits.names.index(sp.names[0])
            ok = self.limits.lower[i] <= sp.q[0] <= self.limits.upper[i]
            return "" if ok else f"{sp.names[0]}={sp.q[0]:.4f} outside its limits"
        return self.limits.check_setpoint(sp)

    def _rpdo2(self, d: _Drive, data: bytes) -> None:
        v = unpack("rpdo2", data)
        if v is None:
            self._reject("bad_length", f"node {d.node.id}: RPDO2 with {len(data)} bytes")
            return
        cw, mode, force = v
        if mode not in (0, cn.MODE_POSITION, cn.MODE_GRASP) or (mode == cn.MODE_GRASP and not d.node.gripper):
            self._reject("bad_mode", f"node {d.node.id}: mode {mode}")
            return
        if cw == cn.CW_QUICK_STOP:
            if d.drive != "fault":
                d.drive, d.pending = "quick_stop", None
        elif cw == cn.CW_FAULT_RESET:  # acts in Fault only, and only once its cause is gone
            if d.drive == "fault" and not (d.fault_code == cn.EMCY_HEARTBEAT and self._master_silent(d)):
                d.drive, d.fault_code = "switched_on", 0
                self._send(0x80 + d.node.id, struct.pack("<HB5s", 0x0000, 0x00, b""))
        elif cw == cn.CW_DISABLE_VOLTAGE:
            if d.drive != "fault":
                d.drive, d.pending = "switched_on", None
        elif cw == cn.CW_ENABLE:
            if d.drive in ("quick_stop", "fault"):
                self._reject("fault_active", f"node {d.node.id}: enable while in {d.drive}; leave it first")
                return
            d.drive = "enabled"
        else:
            self._reject("bad_controlword", f"node {d.node.id}: controlword 0x{cw:04X}")
            return
        if d.node.gripper and mode == cn.MODE_GRASP and d.drive == "enabled":
            reason = self.limits.check_grasp_force(force * 0.01)
            if reason:
                self._reject("limits", f"node {d.node.id}: {reason}")
                return
            self._sync_estop()
            self.sim.gripper(GripperCommand.grasp(force * 0.01))
        d.mode = mode or d.mode
        self._sync_estop()
        self.accepted["rpdo2"] += 1

    def _sync(self) -> None:
        names: list[str] = []
        q: list[float] = []
        dq: list[float] = []
        for d in self.drives.values():
            if d.pending is None or d.drive != "enabled" or d.nmt != "OPERATIONAL":
                d.pending = None
                continue
            v, d.pending = d.pending, None
            if d.node.is_base:
                self.sim.set_base_velocity(v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3)
            elif d.node.gripper:
                if d.mode == cn.MODE_POSITION:
                    self.sim.gripper_to(v[0] * d.node.unit)
            else:
                names.append(str(d.node.joint))
                q.append(v[0] * d.node.unit)
                dq.append(v[1] * d.node.unit)
            self.accepted["rpdo1"] += 1
        if names:
            self.sim.set_joint_targets(JointSetpoint(tuple(names), q, dq))
        self._send_tpdos()

    def _send_tpdos(self) -> None:
        st = self.sim.state()
        for d in self.drives.values():
            if d.nmt != "OPERATIONAL":
                continue
            nid = d.node.id
            if d.node.is_base:
                x, y, yaw = st.base
                vx, vy, wz = st.base_velocity
                self._send(0x180 + nid, pack("tpdo1_base", round(x * 1e6), round(y * 1e6)))
                self._send(0x280 + nid, pack("tpdo2_base", d.statusword(), round(yaw * 1e6)))
                self._send(
                    0x380 + nid,
                    pack("tpdo3_base", *(int(np.clip(round(v * 1e3), -32768, 32767)) for v in (vx, vy, wz))),
                )
            else:
                i = st.names.index(d.node.joint)
                self._send(
                    0x180 + nid, pack("tpdo1_joint", round(st.q[i] / d.node.unit), round(st.dq[i] / d.node.unit))
                )
                self._send(0x280 + nid, pack("tpdo2_joint", d.statusword()))

    # ------------------------------------------------------------------ SDO (expedited only)
    def _sdo(self, d: _Drive, data: bytes) -> None:
        nid = d.node.id
        if len(data) != 8:
            self._reject("bad_length", f"node {nid}: SDO request with {len(data)} bytes")
            return
        cmd, index, sub = data[0], int.from_bytes(data[1:3], "little"), data[3]
        head = data[1:4]

        def abort(code: int, why: str) -> None:
            self._reject("sdo_abort", f"node {nid}: SDO 0x{index:04X}:{sub}: {why}")
            self._send(0x580 + nid, bytes([0x80]) + head + code.to_bytes(4, "little"))

        if cmd & 0xE0 == 0x20:  # download
            if not cmd & 0x02:
                abort(SDO_ABORT_BAD_CMD, "only expedited downloads are supported")
                return
            size = 4 - ((cmd >> 2) & 0x3) if cmd & 0x01 else 4
            value = int.from_bytes(data[4 : 4 + size], "little")
            if (index, sub) == (0x1017, 0):
                if value > 10_000:
                    abort(SDO_ABORT_RANGE, f"heartbeat time {value} ms > 10000")
                    return
                d.hb_ms = value
            elif (index, sub) == (0x1016, 1):
                d.consumer = value
                self._master_hb = time.monotonic()
            else:
                abort(SDO_ABORT_NO_OBJECT, "no such writable object")
                return
            self._send(0x580 + nid, bytes([0x60]) + head + b"\x00\x00\x00\x00")
            self.accepted["sdo"] += 1
        elif cmd == 0x40:  # upload
            values = {(0x1017, 0): (d.hb_ms, 2), (0x1016, 1): (d.consumer, 4), (0x6041, 0): (d.statusword(), 2)}
            if (index, sub) not in values:
                abort(SDO_ABORT_NO_OBJECT, "no such readable object")
                return
            value, size = values[(index, sub)]
            resp = bytes([0x43 | ((4 - size) << 2)]) + head + value.to_bytes(4, "little")
            self._send(0x580 + nid, resp)
            self.accepted["sdo"] += 1
        else:
            abort(SDO_ABORT_BAD_CMD, f"command specifier 0x{cmd:02X}")

    def stats(self) -> dict[str, Any]:
        return {
            "rejected": self.rejects.counts(),
            "rejected_total": self.rejects.total,
            "accepted": dict(self.accepted),
            "ignored": self.ignored,
            "sim_time": self.sim.time,
        }
