"""The ``can`` backend: the robot's drives as CANopen nodes (``robots/<robot>/can_nodes.toml``).

The HAL is the CANopen master (node 1). ``canopen`` provides the protocol services: NMT commands, the
SDO client (heartbeat configuration at configure()), the SYNC producer (the control rate) and the
master's heartbeat producer. The frames that carry data -- TPDOs, heartbeats, EMCY -- are parsed here,
strictly: a frame of the wrong length or with an implausible value is rejected and counted (and never
updates the state). Setpoints go out as RPDO1 (applied by the drives at the next SYNC), the
controlword (enable, quick stop = e-stop, fault reset) and the gripper mode as RPDO2.
"""

from __future__ import annotations

import logging
import struct
import threading
import time
from typing import Any

import numpy as np

from rlgp_exec.hal import can_nodes as cn
from rlgp_exec.hal.can_nodes import CanNode, load_can_map, pack, unpack
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import GripperAction, GripperCommand, HalError, JointSetpoint, RobotState
from rlgp_exec.robot import load_robot

__all__ = ["CanBackend"]

log = logging.getLogger(__name__)

_PLAUSIBLE = 0.5  # [m|rad] feedback further than this outside the joint limits is rejected
_EMCY_TEXT = {cn.EMCY_HEARTBEAT: "master heartbeat lost", cn.EMCY_LIMITS: "setpoint outside the limits"}


class CanBackend(RobotInterface):
    backend = "can"

    def __init__(
        self,
        robot: str = "hsr",
        bus: Any = None,
        interface: str = "virtual",
        channel: str = "rlgp",
        heartbeat_timeout: float = 0.25,
        sdo_timeout: float = 0.5,
    ) -> None:
        super().__init__(load_robot(robot), heartbeat_timeout)
        self.map = load_can_map(self.model)
        self._bus = bus
        self._bus_args: dict[str, Any] = {"interface": interface, "channel": channel}
        self.sdo_timeout = sdo_timeout
        self.network: Any = None
        self._lock = threading.Lock()
        self._periodic: Any = None
        n = {d.id: d for d in self.map.nodes}
        self._nodes: dict[int, CanNode] = n
        self._hb_wall = dict.fromkeys(n, -np.inf)
        self._hb_state = dict.fromkeys(n, 0)
        self._fb_wall = dict.fromkeys(n, -np.inf)
        self._q = {d.joint: np.nan for d in self.map.joints}
        self._dq = {d.joint: 0.0 for d in self.map.joints}
        self._status = dict.fromkeys(n, 0)
        self._odom = [np.nan, np.nan, np.nan]
        self._twist = [0.0, 0.0, 0.0]
        self._emcy: dict[int, set[int]] = {i: set() for i in n}
        self._lo = dict(zip(self.limits.names, self.limits.lower, strict=True))
        self._hi = dict(zip(self.limits.names, self.limits.upper, strict=True))

    # ------------------------------------------------------------------ lifecycle hooks
    def _on_configure(self) -> None:
        import can
        import canopen

        bus = self._bus if self._bus is not None else can.Bus(**self._bus_args)
        net = canopen.Network(bus)
        self.network = net
        for nid in self._nodes:  # our strict parsers first, canopen's own parsers removed
            net.subscribe(0x180 + nid, self._on_tpdo1)
            net.subscribe(0x280 + nid, self._on_tpdo2)
            net.subscribe(0x380 + nid, self._on_tpdo3)
        net.connect()
        bc = self.map.bus
        for nid in self._nodes:
            node = canopen.RemoteNode(nid, canopen.ObjectDictionary())
            net.add_node(node)
            net.unsubscribe(0x700 + nid, node.nmt.on_heartbeat)
            net.unsubscribe(0x80 + nid, node.emcy.on_emcy)
            net.subscribe(0x700 + nid, self._on_heartbeat)
            net.subscribe(0x80 + nid, self._on_emcy)
            node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout
        net.nmt.send_command(0x80)  # all nodes pre-operational
        for nid, node in net.items():
            what = f"node {nid} ({self._nodes[nid].joint or 'base'})"
            try:
                node.sdo.download(0x1017, 0, struct.pack("<H", bc.node_heartbeat_ms))
                node.sdo.download(0x1016, 1, struct.pack("<I", (bc.master_node_id << 16) | bc.consumer_timeout_ms))
            except Exception as e:  # canopen raises SdoCommunicationError / SdoAbortedError
                raise HalError(f"can: {what} did not accept its heartbeat configuration: {e}") from e
        self._periodic = net.send_periodic(0x700 + bc.master_node_id, b"\x05", bc.master_heartbeat)
        net.nmt.send_command(0x01)  # start all nodes
        net.sync.start(bc.sync_period)
        log.info("can: %d nodes configured and started, SYNC every %.0f ms", len(self._nodes), bc.sync_period * 1e3)

    def _on_activate(self) -> None:
        for nid in self._nodes:
            self._rpdo2(nid, cn.CW_ENABLE, cn.MODE_POSITION, 0)

    def _on_shutdown(self) -> None:
        net = self.network
        if net is None:
            return
        try:
            net.sync.stop()
            if self._periodic is not None:
                self._periodic.stop()
            net.nmt.send_command(0x80)  # back to pre-operational: drives stop consuming PDOs
        except Exception as e:
            log.debug("can: shutdown commands failed: %s", e)
        net.disconnect()
        self.network = None

    def wait_for_robot(self, timeout: float = 10.0) -> bool:
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.heartbeat_ok():
                return True
            time.sleep(0.01)
        return False

    # ------------------------------------------------------------------ incoming (notifier thread)
    def _node(self, can_id: int, data: Any, layout_joint: str, layout_base: str | None) -> tuple[Any, ...] | None:
        nid = can_id & 0x7F
        node = self._nodes[nid]
        layout = layout_base if node.is_base else layout_joint
        if layout is None:
            self.rejects.reject("unexpected", f"frame 0x{can_id:X} is not used for node {nid}")
            return None
        v = unpack(layout, bytes(data))
        if v is None:
            self.rejects.reject("bad_length", f"frame 0x{can_id:X} with {len(data)} bytes")
        return v

    def _on_tpdo1(self, can_id: int, data: Any, ts: float) -> None:
        v = self._node(can_id, data, "tpdo1_joint", "tpdo1_base")
        if v is None:
            return
        node = self._nodes[can_id & 0x7F]
        if node.is_base:
            with self._lock:
                self._odom[0], self._odom[1] = v[0] * 1e-6, v[1] * 1e-6
            return
        q, dq = v[0] * node.unit, v[1] * node.unit
        j = str(node.joint)
        if not (self._lo[j] - _PLAUSIBLE <= q <= self._hi[j] + _PLAUSIBLE) or abs(dq) > 100.0:
            self.rejects.reject("implausible", f"node {node.id} ({j}): position {q:.3f}, velocity {dq:.3f}")
            return
        with self._lock:
            self._q[j], self._dq[j] = q, dq
            self._fb_wall[node.id] = time.monotonic()

    def _on_tpdo2(self, can_id: int, data: Any, ts: float) -> None:
        v = self._node(can_id, data, "tpdo2_joint", "tpdo2_base")
        if v is None:
            return
        nid = can_id & 0x7F
        with self._lock:
            self._status[nid] = v[0]
            if self._nodes[nid].is_base:
                self._odom[2] = v[1] * 1e-6
                self._fb_wall[nid] = time.monotonic()

    def _on_tpdo3(self, can_id: int, data: Any, ts: float) -> None:
        v = self._node(can_id, data, "", "tpdo3_base") if self._nodes[can_id & 0x7F].is_base else None
        if v is None:
            if not self._nodes[can_id & 0x7F].is_base:
                self.rejects.reject("unexpected", f"TPDO3 0x{can_id:X} from a joint node")
            return
        with self._lock:
            self._twist = [v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3]

    def _on_heartbeat(self, can_id: int, data: Any, ts: float) -> None:
        if len(data) != 1 or (data[0] & 0x7F) not in (0x00, 0x04, 0x05, 0x7F):
            self.rejects.reject("bad_heartbeat", f"heartbeat 0x{can_id:X}: {bytes(data).hex()}")
            return
        with self._lock:
            self._hb_wall[can_id & 0x7F] = time.monotonic()
            self._hb_state[can_id & 0x7F] = data[0] & 0x7F

    def _on_emcy(self, can_id: int, data: Any, ts: float) -> None:
        if len(data) != 8:
            self.rejects.reject("bad_emcy", f"EMCY 0x{can_id:X} with {len(data)} bytes")
            return
        code = int.from_bytes(bytes(data[:2]), "little")
        nid = can_id & 0x7F
        with self._lock:
            if code & 0xFF00 == 0:
                self._emcy[nid].clear()
            else:
                self._emcy[nid].add(code)
        if code:
            log.warning("can: EMCY from node %d: 0x%04X %s", nid, code, _EMCY_TEXT.get(code, ""))

    # ------------------------------------------------------------------ state
    def heartbeat_ok(self) -> bool:
        if self.network is None:
            return False
        now, t = time.monotonic(), self.heartbeat_timeout
        with self._lock:
            return all(
                now - self._hb_wall[n] <= t and self._hb_state[n] == 0x05 and now - self._fb_wall[n] <= t
                for n in self._nodes
            )

    def _latest_state(self) -> RobotState | None:
        with self._lock:
            if any(np.isnan(v) for v in self._q.values()) or any(np.isnan(v) for v in self._odom):
                return None
            faults = tuple(
                f"node {n} ({self._nodes[n].joint or 'base'}): EMCY 0x{c:04X} {_EMCY_TEXT.get(c, '')}".strip()
                for n, codes in self._emcy.items()
                for c in sorted(codes)
            )
            estopped = any(not (s & cn.SW_NOT_QUICK_STOP) or (s & cn.SW_FAULT) for s in self._status.values())
            return RobotState(
                stamp=time.monotonic(),
                names=self.joint_names,
                q=[self._q[n] for n in self.joint_names],
                dq=[self._dq[n] for n in self.joint_names],
                base=(self._odom[0], self._odom[1], self._odom[2]),
                base_velocity=(self._twist[0], self._twist[1], self._twist[2]),
                gripper=self._q[self.limits.gripper_joint],
                estopped=estopped,
                faults=faults,
            )

    # ------------------------------------------------------------------ outgoing
    def _send(self, cob_id: int, data: bytes) -> None:
        if self.network is None:
            raise HalError("can: not configured")
        self.network.send_message(cob_id, data)

    def _rpdo2(self, nid: int, cw: int, mode: int, force_centi_n: int) -> None:
        self._send(0x300 + nid, pack("rpdo2", cw, mode, force_centi_n))

    def _send_setpoint(self, sp: JointSetpoint) -> None:
        for name, q, dq in zip(sp.names, sp.q, sp.dq, strict=True):
            node = self.map.by_joint(name)
            self._send(0x200 + node.id, pack("rpdo1_joint", round(q / node.unit), round(dq / node.unit)))

    def _send_base_velocity(self, vx: float, vy: float, wz: float) -> None:
        self._send(0x200 + self.map.base.id, pack("rpdo1_base", round(vx * 1e3), round(vy * 1e3), round(wz * 1e3)))

    def _send_gripper(self, cmd: GripperCommand) -> None:
        node = self.map.by_joint(self.limits.gripper_joint)
        if cmd.action is GripperAction.GRASP:
            self._rpdo2(node.id, cn.CW_ENABLE, cn.MODE_GRASP, round(cmd.force * 100))
            return
        m = self.model.manipulator()
        target = m.open if cmd.action is GripperAction.OPEN else m.closed
        self._rpdo2(node.id, cn.CW_ENABLE, cn.MODE_POSITION, 0)
        self._send(0x200 + node.id, pack("rpdo1_joint", round(target / node.unit), 0))

    def _send_estop(self, engaged: bool) -> None:
        cw = cn.CW_QUICK_STOP if engaged else cn.CW_FAULT_RESET
        for nid in self._nodes:
            self._rpdo2(nid, cw, 0, 0)
