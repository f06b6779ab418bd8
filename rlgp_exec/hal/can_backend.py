"""The ``can`` backend: the robot's drives as CANopen nodes (``robots/<robot>/can_nodes.toml``).

The HAL is the CANopen master (node 1). ``canopen`` provides the protocol services: NMT commands, the
SDO client (heartbeat configuration), the SYNC producer (the control rate) and the master's heartbeat
producer. The frames that carry data -- TPDOs, heartbeats, EMCY -- are parsed here, strictly: a frame of
the wrong length or with an implausible value is rejected and counted (and never updates the state).
Setpoints go out as RPDO1 (applied by the drives at the next SYNC), the controlword (enable, quick stop =
e-stop, fault reset / disable voltage = re-arm) and the gripper mode as RPDO2.

Supervision (a thread of its own: SDO transfers cannot run in the receive thread). A node whose heartbeat
reports another NMT state than OPERATIONAL, a boot-up or a heartbeat back after a silence, or that an NMT
frame not sent by this HAL addressed, is re-initialised: its heartbeat objects (0x1017, 0x1016:01) read back
and re-written when changed, the node started, then re-enabled only if no e-stop is latched; until then the
HAL refuses motion, and if that fails the HAL quick-stops every drive and goes to ERROR with the reason. The
heartbeat objects are also read back at configure, after any SDO request to a node that this HAL did not
send, and every ``audit_period``. While the e-stop is latched, a drive that leaves quick stop is stopped
again at once and one that reports operation enabled is a fault (in ``RobotState.faults``) until
``rearm()``; while it is not, a drive enabled or disabled against what ``activate()`` set is set back. An
EMCY error reset (0x0000) clears a node's EMCY codes only once its statusword no longer reports a fault.

The e-stop is confirmed by each drive's statusword (quick stop active, or Fault): a drive that has not
reported it within the heartbeat timeout of the quick stop, or whose statusword has not been heard for that
long, is sent the quick stop again every heartbeat timeout until it does (:meth:`CanBackend.estop_status`).
Every quick stop sent while the e-stop is latched and ``rearm()``'s fault reset share a lock, so a release
is never followed by a late quick stop that latches a drive again.

CAN frames carry no sender identity: a node that impersonates the master can send every frame this HAL
sends, so the HAL can only notice a rogue enable (by the frame or the next statusword) and re-latch the
quick stop within about one SYNC period; a guaranteed stop against a hostile bus needs a hardwired safety
function (STO) outside the bus.
"""

from __future__ import annotations

import enum
import logging
import struct
import threading
import time
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any

import can
import canopen
import numpy as np
from canopen import SdoAbortedError, SdoCommunicationError

from rlgp_exec.hal import can_nodes as cn
from rlgp_exec.hal.can_nodes import CanNode, load_can_map, pack, unpack
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import (
    EstopStatus,
    GripperAction,
    GripperCommand,
    HalError,
    JointSetpoint,
    Lifecycle,
    RobotState,
)
from rlgp_exec.hal.validate import RejectCounter
from rlgp_exec.robot import load_robot

__all__ = ["CanBackend", "NodeHealth", "NodeStatus"]

log = logging.getLogger(__name__)

_PLAUSIBLE = 0.5  # [m|rad] feedback further than this outside the joint limits is rejected
_EMCY_TEXT = {cn.EMCY_HEARTBEAT: "master heartbeat lost", cn.EMCY_LIMITS: "setpoint outside the limits"}
_ATTEMPTS = 3  # configurations of a node before the HAL faults (a foreign SDO exchange can garble one)
_FOREIGN_SETTLE = 0.03  # [s] before reading a node back after a foreign SDO request: its exchange ends first
_ACK_TIMEOUT = 1.0  # [s] for a drive to report the state we commanded before we command it again
_ECHO_WINDOW = 0.5  # [s] a frame we sent that comes back this soon is our own (a bus that echoes sends)


class _Network(canopen.Network):
    """canopen's network, remembering what it sent: some buses (receive_own_messages, a few adapters) hand
    our own frames back, and those are not another master's."""

    def __init__(self, bus: Any) -> None:
        super().__init__(bus)
        self._sent: deque[tuple[float, int, bytes]] = deque(maxlen=512)
        self._sent_lock = threading.Lock()

    def send_message(self, can_id: int, data: bytes, remote: bool = False) -> None:
        with self._sent_lock:
            self._sent.append((time.monotonic(), can_id, bytes(data)))
        super().send_message(can_id, data, remote)

    def sent_by_us(self, can_id: int, data: bytes) -> bool:
        now = time.monotonic()
        with self._sent_lock:
            return any(c == can_id and d == data and now - t <= _ECHO_WINDOW for t, c, d in self._sent)


class NodeHealth(enum.Enum):
    """The HAL's view of one node."""

    OK = "ok"  # operational, heartbeat objects verified
    REINIT = "reinit"  # being re-initialised: the HAL refuses motion meanwhile
    FAULT = "fault"  # re-initialisation failed: the HAL is in ERROR


@dataclass(frozen=True)
class NodeStatus:
    id: int
    name: str  # the joint, or "base"
    health: NodeHealth
    nmt_state: str  # from its last heartbeat
    reason: str  # why it was last re-initialised ("" if never)
    reinits: int  # completed re-initialisations


@dataclass
class _Watch:
    """Supervision state of one node (guarded by the backend's lock)."""

    hb_wall: float = -np.inf
    hb_state: int = 0
    silent: bool = False  # its heartbeat stopped (no motion: stale)
    probed: bool = False  # asked by SDO for its heartbeat objects during this silence
    fb_wall: float = -np.inf
    status: int = 0  # last statusword
    sw_wall: float = -np.inf  # [s, monotonic] it arrived
    emcy: set[int] = field(default_factory=set)
    emcy_reset: bool = False  # an EMCY error reset came: codes clear at the next fault-free statusword
    health: NodeHealth = NodeHealth.OK
    reason: str = ""
    reinits: int = 0
    qs_sent: float = -np.inf  # last quick stop sent
    qs_acked: bool = True  # it reported quick stop/fault since the e-stop was latched
    cw_sent: float = -np.inf  # last enable / disable voltage we sent
    cw_acked: bool = True  # it reported that state since (statuswords in flight still show the old one)
    enable_fault: bool = False  # it reported operation enabled while e-stopped (until rearm)


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
        consumer_timeout_ms: int | None = None,
        audit_period: float = 2.0,
    ) -> None:
        super().__init__(load_robot(robot), heartbeat_timeout)
        self.map = load_can_map(self.model)
        self._bus = bus
        self._bus_args: dict[str, Any] = {"interface": interface, "channel": channel}
        self.sdo_timeout = sdo_timeout
        self.audit_period = audit_period
        bc = self.map.bus
        #: the heartbeat objects every node must hold: 0x1017 [ms], 0x1016:01
        self.heartbeat_objects = (bc.node_heartbeat_ms, bc.consumer_heartbeat(consumer_timeout_ms))
        self.network: Any = None
        self._lock = threading.Lock()
        self._periodic: Any = None
        n = {d.id: d for d in self.map.nodes}
        self._nodes: dict[int, CanNode] = n
        self._w = {i: _Watch() for i in n}
        self._q = {d.joint: np.nan for d in self.map.joints}
        self._dq = {d.joint: 0.0 for d in self.map.joints}
        self._odom = [np.nan, np.nan, np.nan]
        self._twist = [0.0, 0.0, 0.0]
        self._lo = dict(zip(self.limits.names, self.limits.lower, strict=True))
        self._hi = dict(zip(self.limits.names, self.limits.upper, strict=True))
        #: frames addressed to our nodes that this HAL did not send (another master on the bus)
        self.foreign = RejectCounter("hal[can] frames not from this master")
        self.fault_reason = ""  # why the HAL went to ERROR
        self._latched = False  # our e-stop (or our fault): no drive may be enabled
        self._enable_wanted = False  # activate() enabled the drives and no e-stop since
        # held from reading _latched to sending on it (quick stops, rearm's release): taken before _lock
        self._estop_lock = threading.Lock()
        self.estop_resends = 0  # quick stops sent again to drives that did not confirm the e-stop
        self._estop_episode_resends = 0  # of the e-stop latched now (its confirmation is logged once)
        self._pending: dict[int, float] = {}  # node -> not before [monotonic s]: to re-initialise
        self._busy: set[int] = set()  # nodes the supervisor is re-initialising (their NMT changes are ours)
        self._wake = threading.Event()
        self._stop = threading.Event()
        self._supervisor: threading.Thread | None = None

    # ------------------------------------------------------------------ lifecycle hooks
    def _on_configure(self) -> None:
        bus = self._bus if self._bus is not None else can.Bus(**self._bus_args)
        net = _Network(bus)
        self.network = net
        net.subscribe(0x000, self._guard(self._on_foreign_nmt))
        for nid in self._nodes:  # our strict parsers first, canopen's own parsers removed
            net.subscribe(0x180 + nid, self._guard(self._on_tpdo1))
            net.subscribe(0x280 + nid, self._guard(self._on_tpdo2))
            net.subscribe(0x380 + nid, self._guard(self._on_tpdo3))
            for fn in (0x200, 0x300, 0x600):
                net.subscribe(fn + nid, self._guard(self._on_foreign))
        net.connect()
        bc = self.map.bus
        for nid in self._nodes:
            node = canopen.RemoteNode(nid, canopen.ObjectDictionary())
            net.add_node(node)
            net.unsubscribe(0x700 + nid, node.nmt.on_heartbeat)
            net.unsubscribe(0x80 + nid, node.emcy.on_emcy)
            net.subscribe(0x700 + nid, self._guard(self._on_heartbeat))
            net.subscribe(0x80 + nid, self._guard(self._on_emcy))
            node.sdo.RESPONSE_TIMEOUT = self.sdo_timeout
        net.nmt.send_command(cn.NMT_PRE_OPERATIONAL)  # all nodes
        for nid in self._nodes:
            for _ in range(_ATTEMPTS):  # a late answer on a loaded machine is not yet a broken node
                why = self._ensure_heartbeat_objects(nid)
                if not why:
                    break
            if why:
                raise HalError(f"can: {self._what(nid)}: {why}")
        self._periodic = net.send_periodic(0x700 + bc.master_node_id, b"\x05", bc.master_heartbeat)
        t0 = time.monotonic()
        net.nmt.send_command(cn.NMT_START)  # all nodes
        late = self._wait_operational(self._nodes, t0)
        if late:
            raise HalError(f"can: {', '.join(self._what(n) for n in late)} did not report OPERATIONAL after start")
        net.sync.start(bc.sync_period)
        self._supervisor = threading.Thread(target=self._supervise, name="can-supervisor", daemon=True)
        self._supervisor.start()
        log.info(
            "can: %d nodes configured, verified and started, SYNC every %.0f ms, heartbeat consumers 0x%08X",
            len(self._nodes),
            bc.sync_period * 1e3,
            self.heartbeat_objects[1],
        )

    def _on_activate(self) -> None:
        with self._lock:  # every drive awaits its enable before any statusword is judged against it
            self._enable_wanted = True
            self._mark_controlword_sent(self._nodes)
        for nid in self._nodes:
            self._controlword(nid, cn.CW_ENABLE, cn.MODE_POSITION)

    def _on_shutdown(self) -> None:
        self._stop.set()
        self._wake.set()
        if self._supervisor is not None:
            self._supervisor.join(timeout=5.0)
        net = self.network
        if net is None:
            return
        try:
            net.sync.stop()
            if self._periodic is not None:
                self._periodic.stop()
            net.nmt.send_command(cn.NMT_PRE_OPERATIONAL)  # drives stop consuming PDOs
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

    def node_status(self) -> tuple[NodeStatus, ...]:
        with self._lock:
            return tuple(
                NodeStatus(
                    nid,
                    self._nodes[nid].joint or "base",
                    w.health,
                    cn.NMT_STATES.get(w.hb_state, f"0x{w.hb_state:02X}"),
                    w.reason,
                    w.reinits,
                )
                for nid, w in self._w.items()
            )

    def _what(self, nid: int) -> str:
        return f"node {nid} ({self._nodes[nid].joint or 'base'})"

    # ------------------------------------------------------------------ incoming (notifier thread)
    def _guard(self, handler: Any) -> Any:
        """``handler`` that counts and logs its own failure: canopen would swallow it silently."""

        def guarded(can_id: int, data: Any, ts: float) -> None:
            try:
                handler(can_id, data, ts)
            except Exception as e:
                self.rejects.reject("internal", f"frame 0x{can_id:X} {bytes(data).hex()}: {type(e).__name__}: {e}")
                log.exception("can: handler of frame 0x%X failed", can_id)

        return guarded

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
            self._w[node.id].fb_wall = time.monotonic()

    def _on_tpdo2(self, can_id: int, data: Any, ts: float) -> None:
        v = self._node(can_id, data, "tpdo2_joint", "tpdo2_base")
        if v is None:
            return
        nid, sw = can_id & 0x7F, int(v[0])
        with self._lock:
            w = self._w[nid]
            w.status, w.sw_wall = sw, time.monotonic()
            if self._nodes[nid].is_base:
                self._odom[2] = v[1] * 1e-6
                w.fb_wall = time.monotonic()
            if w.emcy_reset and not sw & cn.SW_FAULT:
                w.emcy_reset = False
                if w.emcy:
                    log.info("can: %s: EMCY codes %s reset", self._what(nid), sorted(w.emcy))
                w.emcy.clear()
        self._watch_statusword(nid, sw)

    def _watch_statusword(self, nid: int, sw: int) -> None:
        """Hold the e-stop: a drive that leaves quick stop while it is latched is stopped again at once."""
        with self._estop_lock:  # a rearm between judging this statusword and acting on it would be undone
            self._judge_statusword(nid, sw)

    def _judge_statusword(self, nid: int, sw: int) -> None:
        now = time.monotonic()
        with self._lock:
            w, latched = self._w[nid], self._latched
            if not latched:
                enabled = cn.operation_enabled(sw)
                if enabled == self._enable_wanted or cn.stopped(sw):
                    w.cw_acked |= enabled == self._enable_wanted
                    return
                if not w.cw_acked and now - w.cw_sent <= _ACK_TIMEOUT:
                    return
            elif cn.stopped(sw):
                w.qs_acked = True
                return
            elif not w.qs_acked and now - w.qs_sent <= self.heartbeat_timeout:
                return  # sent before our quick stop reached it
            newly = latched and w.qs_acked and cn.operation_enabled(sw) and not w.enable_fault
            w.enable_fault |= newly
            recent = now - w.qs_sent <= self.map.bus.sync_period
        if not latched:  # a drive (dis)abled by another master goes back to what activate() set
            state = "operation enabled" if enabled else "disabled"
            self.foreign.reject("foreign_enable", f"{self._what(nid)} reports {state}, not commanded here: undone")
            self._controlword(nid, cn.CW_DISABLE_VOLTAGE if enabled else cn.CW_ENABLE)
            return
        if newly:
            log.error(
                "can: %s reports operation enabled (statusword 0x%04X) while the e-stop is latched: "
                "a frame not from this HAL enabled it; quick stop again",
                self._what(nid),
                sw,
            )
        if not recent:
            self._quick_stop(nid)
            self._count_resend()

    def _on_tpdo3(self, can_id: int, data: Any, ts: float) -> None:
        v = self._node(can_id, data, "", "tpdo3_base") if self._nodes[can_id & 0x7F].is_base else None
        if v is None:
            if not self._nodes[can_id & 0x7F].is_base:
                self.rejects.reject("unexpected", f"TPDO3 0x{can_id:X} from a joint node")
            return
        with self._lock:
            self._twist = [v[0] * 1e-3, v[1] * 1e-3, v[2] * 1e-3]

    def _on_heartbeat(self, can_id: int, data: Any, ts: float) -> None:
        if len(data) != 1 or (data[0] & 0x7F) not in cn.NMT_STATES:
            self.rejects.reject("bad_heartbeat", f"heartbeat 0x{can_id:X}: {bytes(data).hex()}")
            return
        nid, s = can_id & 0x7F, data[0] & 0x7F
        with self._lock:
            w = self._w[nid]
            # a node left waiting by its re-initialisation (it was silent) is taken up again
            prev, back = w.hb_state, w.health is NodeHealth.REINIT and nid not in self._pending
            w.hb_wall, w.hb_state, w.silent, w.probed = time.monotonic(), s, False, False
            ours = nid in self._busy and s != 0x00
        if self._supervisor is None or ours or self._lifecycle is Lifecycle.ERROR:
            return
        name = cn.NMT_STATES[s]
        if s == 0x00:
            self._request(nid, "boot-up: the node was reset")
        elif s != prev:
            self._request(nid, f"NMT state {name} (was {cn.NMT_STATES.get(prev, hex(prev))}), not commanded here")
        elif back:
            self._request(nid, "heartbeat back")

    def _on_emcy(self, can_id: int, data: Any, ts: float) -> None:
        if len(data) != 8:
            self.rejects.reject("bad_emcy", f"EMCY 0x{can_id:X} with {len(data)} bytes")
            return
        code = int.from_bytes(bytes(data[:2]), "little")
        nid = can_id & 0x7F
        held = False
        with self._lock:
            w = self._w[nid]
            if code & 0xFF00 == 0:
                w.emcy_reset = True  # takes effect at a statusword without the fault bit
                held = bool(w.status & cn.SW_FAULT) and bool(w.emcy)
            else:
                w.emcy.add(code)
                w.emcy_reset = False
        if code & 0xFF00:
            log.warning("can: EMCY from node %d: 0x%04X %s", nid, code, _EMCY_TEXT.get(code, ""))
        elif held:
            log.warning("can: EMCY error reset from node %d: its statusword still reports a fault, kept", nid)

    def _on_foreign(self, can_id: int, data: Any, ts: float) -> None:
        """An RPDO or SDO request to one of our nodes: not ours, so another master is on the bus."""
        nid, fn, raw = can_id & 0x7F, can_id & 0x780, bytes(data)
        if self.network.sent_by_us(can_id, raw):
            return
        kind = {0x200: "RPDO1", 0x300: "RPDO2", 0x600: "SDO request"}[fn]
        self.foreign.reject(
            f"foreign_{kind.split()[0].lower()}", f"{kind} 0x{can_id:X} [{raw.hex()}] to {self._what(nid)}"
        )
        if not (fn == 0x300 and raw[:2] == cn.CW_QUICK_STOP.to_bytes(2, "little")):
            self._quick_stop_if_latched(nid)
        if fn == 0x600:
            self._request(nid, f"SDO request [{raw.hex()}] from another master", settle=_FOREIGN_SETTLE)

    def _on_foreign_nmt(self, can_id: int, data: Any, ts: float) -> None:
        raw = bytes(data)
        if self.network.sent_by_us(can_id, raw):
            return
        if len(raw) != 2 or raw[0] not in cn.NMT_COMMANDS:
            self.foreign.reject("foreign_nmt", f"malformed NMT frame [{raw.hex()}]")
            return
        targets = [n for n in self._nodes if raw[1] in (0, n)]
        self.foreign.reject("foreign_nmt", f"NMT {cn.NMT_COMMANDS[raw[0]]} for node {raw[1]}")
        for nid in targets:
            self._quick_stop_if_latched(nid)
            self._request(nid, f"NMT {cn.NMT_COMMANDS[raw[0]]} from another master", settle=_FOREIGN_SETTLE)

    # ------------------------------------------------------------------ supervision
    def _request(self, nid: int, reason: str, settle: float = 0.0) -> None:
        """Re-initialise ``nid`` (from the supervisor thread); no motion until it is done."""
        with self._lock:
            w = self._w[nid]
            if w.health is NodeHealth.FAULT or self._supervisor is None or self._stop.is_set():
                return
            if w.health is NodeHealth.OK:
                w.health, w.reason = NodeHealth.REINIT, reason
                log.warning("can: %s: %s: re-initialising it", self._what(nid), reason)
            self._pending[nid] = max(self._pending.get(nid, 0.0), time.monotonic() + settle)
        self._wake.set()

    def _supervise(self) -> None:
        next_audit = time.monotonic() + self.audit_period
        while not self._stop.is_set():
            self._wake.wait(0.05)
            self._wake.clear()
            if self._stop.is_set():
                return
            try:
                self._check_silence()
                self._reinit_pending()
                self._check_acks()
                if time.monotonic() >= next_audit:
                    next_audit = time.monotonic() + self.audit_period
                    self._audit()
            except Exception as e:  # a bug here must not leave the drives unsupervised
                log.exception("can: supervisor failed")
                self._fault(f"supervisor failed: {type(e).__name__}: {e}")
                return

    def _check_silence(self) -> None:
        """A node silent while others talk may have had its heartbeat producer switched off (0x1017 = 0, a
        reset of its communication): asked once by SDO, and re-configured if so. All silent at once is the
        bus or the robot gone (or this process starved): stale, nothing to ask."""
        now = time.monotonic()
        with self._lock:
            gone = [n for n, w in self._w.items() if not w.silent and now - w.hb_wall > self.heartbeat_timeout]
            for n in gone:
                self._w[n].silent = True
            alive = not all(w.silent for w in self._w.values())
            ask = [n for n, w in self._w.items() if w.silent and not w.probed and alive]
            for n in ask:
                self._w[n].probed = True
        if gone:
            log.warning("can: no heartbeat for %.2f s from %s", self.heartbeat_timeout, [self._what(n) for n in gone])
        for n in ask:
            self._ensure_heartbeat_objects(n)  # no answer: gone, and stale until it is back

    def _reinit_pending(self) -> None:
        now = time.monotonic()
        with self._lock:
            due = sorted(n for n, t in self._pending.items() if t <= now)
            for n in due:
                del self._pending[n]
            self._busy.update(due)
            settling = bool(self._pending)
        if settling:
            self._wake.set()  # come back for the settling ones
            time.sleep(0.005)
        if not due:
            return
        try:
            failed = self._reinit(due)
        finally:
            with self._lock:
                self._busy.difference_update(due)
        if failed and not self._stop.is_set():  # shutdown() interrupts the waits: no fault then
            self._fault("; ".join(f"{self._what(n)}: re-initialisation failed: {why}" for n, why in failed.items()))

    def _reinit(self, nids: list[int]) -> dict[int, str]:
        """Bring ``nids`` back: heartbeat objects checked (re-written), OPERATIONAL, their controlword.
        Returns the nodes that could not be brought back, with why."""
        failed: dict[int, str] = {}
        todo = list(nids)
        for _ in range(_ATTEMPTS):
            failed_before, failed = failed, {}
            with self._lock:
                stopped = [n for n in todo if self._w[n].hb_state == 0x04]
            for n in stopped:  # SDO is unavailable in STOPPED
                self._send(0x000, bytes([cn.NMT_PRE_OPERATIONAL, n]))
            if stopped:
                self._wait_state(stopped, lambda s: s != 0x04)
            for n in todo:
                why = self._ensure_heartbeat_objects(n)
                if why:
                    failed[n] = why
            ok = [n for n in todo if n not in failed]
            now = time.monotonic()
            with self._lock:
                silent = {n for n in failed if now - self._w[n].hb_wall > self.heartbeat_timeout}
            for n in silent:  # gone, not failed: its next heartbeat takes it up again
                log.warning("can: %s: silent and no SDO answer: no motion until it is back", self._what(n))
                del failed[n]
            t0 = time.monotonic()
            with self._lock:
                idle = [n for n in ok if self._w[n].hb_state != cn.HB_OPERATIONAL or n in failed_before]
            for n in idle:
                self._send(0x000, bytes([cn.NMT_START, n]))
            for n in self._wait_operational(ok, t0):
                with self._lock:
                    w = self._w[n]
                    last = f"{cn.NMT_STATES[w.hb_state]} {time.monotonic() - w.hb_wall:.2f} s ago"
                failed[n] = f"did not report OPERATIONAL after start (last heartbeat: {last})"
            for n in (n for n in ok if n not in failed):
                self._restore_controlword(n)
                with self._lock:
                    w = self._w[n]
                    done = n not in self._pending  # else a new request came while we worked: run again
                    if done:
                        w.health = NodeHealth.OK
                        w.reinits += 1
                if done:
                    log.info("can: %s re-initialised after %s", self._what(n), w.reason)
            todo = list(failed)
            if not todo:
                return {}
        return failed

    def _restore_controlword(self, nid: int) -> None:
        with self._estop_lock:
            if self._latched:
                self._quick_stop(nid)
            elif self._enable_wanted and self._lifecycle is not Lifecycle.ESTOPPED:
                self._controlword(nid, cn.CW_ENABLE, cn.MODE_POSITION)

    def _ensure_heartbeat_objects(self, nid: int) -> str:
        """'' when the node holds our heartbeat objects (re-written when it did not), else why not."""
        sdo, want = self.network[nid].sdo, self.heartbeat_objects

        def read() -> tuple[int, int]:
            return int.from_bytes(sdo.upload(0x1017, 0), "little"), int.from_bytes(sdo.upload(0x1016, 1), "little")

        try:
            have = read()
            if have == want:
                return ""
            if have != (0, 0) or self._supervisor is not None:
                log.warning(
                    "can: %s: heartbeat objects 0x1017=%d ms, 0x1016:01=0x%08X, expected %d ms, 0x%08X: re-writing",
                    self._what(nid),
                    *have,
                    *want,
                )
            sdo.download(0x1017, 0, struct.pack("<H", want[0]))
            sdo.download(0x1016, 1, struct.pack("<I", want[1]))
            have = read()
        except (SdoAbortedError, SdoCommunicationError) as e:
            return f"heartbeat objects 0x1016/0x1017 not accepted: {e}"
        if have != want:
            return f"heartbeat objects read back as 0x1017={have[0]}, 0x1016:01=0x{have[1]:08X}, expected {want}"
        return ""

    def _wait_state(self, nids: Iterable[int], ok: Any, since: float = -np.inf) -> list[int]:
        """The nodes of ``nids`` whose heartbeat did not satisfy ``ok`` (newer than ``since``) in time."""
        nids = list(nids)
        end = time.monotonic() + max(1.0, 10 * self.map.bus.node_heartbeat_ms * 1e-3)
        while True:
            with self._lock:
                late = [n for n in nids if not (self._w[n].hb_wall > since and ok(self._w[n].hb_state))]
            if not late or time.monotonic() > end or self._stop.is_set():
                return late
            time.sleep(0.002)

    def _wait_operational(self, nids: Iterable[int], since: float) -> list[int]:
        return self._wait_state(nids, lambda s: s == cn.HB_OPERATIONAL, since)

    def _check_acks(self) -> None:
        """Quick stop again, every heartbeat timeout, to drives that have not acknowledged it within the
        heartbeat timeout or whose statusword has not been heard for that long (restarted, or gone)."""
        with self._estop_lock:
            if not self._latched:
                return
            now, t = time.monotonic(), self.heartbeat_timeout
            with self._lock:
                late = [
                    n
                    for n, w in self._w.items()
                    if now - w.qs_sent > t and (not w.qs_acked or now - w.sw_wall > t)
                ]
                confirmed = not late and self._all_stopped(now)
            if late and not self._estop_episode_resends:
                log.warning(
                    "can: %s did not confirm the quick stop within %.2f s: sending it again every %.2f s until they do",
                    [self._what(n) for n in late],
                    t,
                    t,
                )
            for n in late:
                self._quick_stop(n)
                self._count_resend()
            if confirmed and self._estop_episode_resends:
                log.warning(
                    "can: every drive reports quick stop, after %d quick stop re-send(s)", self._estop_episode_resends
                )
                self._estop_episode_resends = 0

    def _count_resend(self) -> None:
        """A quick stop sent again to a drive that did not confirm it (call under ``_estop_lock``)."""
        self.estop_resends += 1
        self._estop_episode_resends += 1

    def _all_stopped(self, now: float) -> bool:
        """Every drive's fresh statusword reports quick stop or Fault (call under ``_lock``)."""
        return all(cn.stopped(w.status) and now - w.sw_wall <= self.heartbeat_timeout for w in self._w.values())

    def estop_status(self) -> EstopStatus:
        with self._estop_lock, self._lock:
            engaged = self._latched
            return EstopStatus(engaged, engaged and self._all_stopped(time.monotonic()), self.estop_resends)

    def _quick_stop_if_latched(self, nid: int) -> None:
        with self._estop_lock:
            if self._latched:
                self._quick_stop(nid)

    def _audit(self) -> None:
        """Read back the heartbeat objects of healthy nodes: a change nobody saw on the bus is caught too."""
        with self._lock:
            nids = [n for n, w in self._w.items() if w.health is NodeHealth.OK and not w.silent]
        for n in nids:
            if self._stop.is_set():
                return
            why = self._ensure_heartbeat_objects(n)
            if why:
                self._request(n, f"audit: {why}")

    def _quick_stop(self, nid: int) -> None:
        with self._lock:
            self._w[nid].qs_sent = time.monotonic()
        self._rpdo2(nid, cn.CW_QUICK_STOP, 0, 0)

    def _controlword(self, nid: int, cw: int, mode: int = 0) -> None:
        """Enable or disable voltage (mode 0 keeps the drive's); its statusword is not checked for a while."""
        with self._lock:
            self._mark_controlword_sent([nid])
        self._rpdo2(nid, cw, mode, 0)

    def _mark_controlword_sent(self, nids: Iterable[int]) -> None:
        """Statuswords of ``nids`` still in flight show the old state for a while (call under ``_lock``)."""
        now = time.monotonic()
        for nid in nids:
            self._w[nid].cw_sent, self._w[nid].cw_acked = now, False

    def _fault(self, reason: str) -> None:
        """Unrecoverable: every drive quick-stopped, the e-stop latched, the HAL in ERROR."""
        with self._lock:
            for w in self._w.values():
                if w.health is NodeHealth.REINIT:
                    w.health = NodeHealth.FAULT
            self.fault_reason = self.fault_reason or reason
            self._latched, self._enable_wanted = True, False
        self._lifecycle = Lifecycle.ERROR
        log.error("can: %s: every drive quick-stopped, HAL in ERROR (shutdown() and rebuild)", reason)
        for nid in self._nodes:
            self._quick_stop(nid)

    # ------------------------------------------------------------------ state
    def heartbeat_ok(self) -> bool:
        if self.network is None or self._lifecycle is Lifecycle.ERROR:
            return False
        now, t = time.monotonic(), self.heartbeat_timeout
        with self._lock:
            return all(
                now - w.hb_wall <= t
                and w.hb_state == cn.HB_OPERATIONAL
                and now - w.fb_wall <= t
                and w.health is NodeHealth.OK
                for w in self._w.values()
            )

    def _latest_state(self) -> RobotState | None:
        with self._lock:
            if any(np.isnan(v) for v in self._q.values()) or any(np.isnan(v) for v in self._odom):
                return None
            faults: list[str] = []
            for n, w in self._w.items():
                what = self._what(n)
                faults += [f"{what}: EMCY 0x{c:04X} {_EMCY_TEXT.get(c, '')}".strip() for c in sorted(w.emcy)]
                if w.status & cn.SW_FAULT:
                    faults.append(f"{what}: statusword reports a fault")
                if w.enable_fault:
                    faults.append(f"{what}: was enabled while the e-stop was latched (by a frame not from this HAL)")
                if w.health is not NodeHealth.OK:
                    faults.append(f"{what}: {w.health.value}: {w.reason}")
            return RobotState(
                stamp=time.monotonic(),
                names=self.joint_names,
                q=[self._q[n] for n in self.joint_names],
                dq=[self._dq[n] for n in self.joint_names],
                base=(self._odom[0], self._odom[1], self._odom[2]),
                base_velocity=(self._twist[0], self._twist[1], self._twist[2]),
                gripper=self._q[self.limits.gripper_joint],
                estopped=any(cn.stopped(w.status) for w in self._w.values()),
                faults=tuple(faults),
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
        with self._estop_lock:  # no quick stop decided before a release goes out after it
            self._send_estop_locked(engaged)

    def _send_estop_locked(self, engaged: bool) -> None:
        if engaged:
            with self._lock:
                self._latched, self._enable_wanted = True, False
                for w in self._w.values():
                    w.qs_acked = False
                self._estop_episode_resends = 0
            for nid in self._nodes:
                self._quick_stop(nid)
            return
        with self._lock:  # rearm(): only onto nodes the HAL trusts
            bad = [
                f"{self._what(n)}: {w.health.value} ({w.reason})"
                for n, w in self._w.items()
                if w.health is not NodeHealth.OK
            ]
            if bad:
                raise HalError(f"can: cannot rearm: {'; '.join(bad)}")
            self._latched = False
            for w in self._w.values():
                w.enable_fault = False
            self._mark_controlword_sent(self._nodes)
        for nid in self._nodes:  # CiA 402: fault reset leaves Fault, disable voltage leaves quick stop
            self._rpdo2(nid, cn.CW_FAULT_RESET, 0, 0)
            self._controlword(nid, cn.CW_DISABLE_VOLTAGE)
