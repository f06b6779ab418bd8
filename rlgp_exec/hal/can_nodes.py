"""The CANopen node map of a robot (``robots/<robot>/can_nodes.toml``) and the PDO frame layouts shared by
the CAN backend (master) and the simulated node set. The TOML documents every object used."""

from __future__ import annotations

import struct
import tomllib
from dataclasses import dataclass
from typing import Any

from rlgp_exec.hal.types import HalError
from rlgp_exec.robot import RobotModel
from rlgp_exec.robots import robot_dir

__all__ = [
    "CW_DISABLE_VOLTAGE",
    "CW_ENABLE",
    "CW_FAULT_RESET",
    "CW_QUICK_STOP",
    "EMCY_HEARTBEAT",
    "EMCY_LIMITS",
    "HB_OPERATIONAL",
    "MODE_GRASP",
    "MODE_POSITION",
    "NMT_COMMANDS",
    "NMT_PRE_OPERATIONAL",
    "NMT_START",
    "NMT_STATES",
    "SW_ENABLED",
    "SW_FAULT",
    "SW_NOT_QUICK_STOP",
    "BusConfig",
    "CanMap",
    "CanNode",
    "load_can_map",
    "operation_enabled",
    "pack",
    "stopped",
    "unpack",
]

# CiA 402 subset
CW_ENABLE, CW_QUICK_STOP, CW_FAULT_RESET, CW_DISABLE_VOLTAGE = 0x000F, 0x0002, 0x0080, 0x0000
SW_ENABLED, SW_FAULT, SW_NOT_QUICK_STOP, SW_TARGET_REACHED = 1 << 2, 1 << 3, 1 << 5, 1 << 10
# CiA 301 NMT: heartbeat states (0x00 = boot-up) and the commands of the NMT frame (COB-ID 0x000)
NMT_STATES = {0x00: "BOOT-UP", 0x04: "STOPPED", 0x05: "OPERATIONAL", 0x7F: "PRE-OPERATIONAL"}
NMT_COMMANDS = {0x01: "start", 0x02: "stop", 0x80: "enter pre-operational", 0x81: "reset node", 0x82: "reset comm"}
HB_OPERATIONAL, NMT_START, NMT_PRE_OPERATIONAL = 0x05, 0x01, 0x80
MODE_POSITION, MODE_GRASP = 1, 4
EMCY_HEARTBEAT, EMCY_LIMITS = 0x8130, 0x8611


def stopped(statusword: int) -> bool:
    """Fault or quick stop active: the drive holds and follows no setpoint."""
    return bool(statusword & SW_FAULT) or not statusword & SW_NOT_QUICK_STOP


def operation_enabled(statusword: int) -> bool:
    """CiA 402 "operation enabled": the drive follows setpoints (bit 2 set, no quick stop, no fault)."""
    return bool(statusword & SW_ENABLED) and not stopped(statusword)


# frame layouts: (function base, struct format)
LAYOUT: dict[str, tuple[int, str]] = {
    "rpdo1_joint": (0x200, "<ii"),  # target position, target velocity [counts, counts/s]
    "rpdo1_base": (0x200, "<hhh"),  # vx, vy [mm/s], wz [mrad/s]
    "rpdo2": (0x300, "<HbH"),  # controlword, mode, grasp force [0.01 N]
    "tpdo1_joint": (0x180, "<ii"),  # position, velocity actual
    "tpdo1_base": (0x180, "<ii"),  # odom x, y [um]
    "tpdo2_joint": (0x280, "<H"),  # statusword
    "tpdo2_base": (0x280, "<Hi"),  # statusword, yaw [urad]
    "tpdo3_base": (0x380, "<hhh"),  # measured vx, vy [mm/s], wz [mrad/s]
}


def pack(layout: str, *values: int) -> bytes:
    return struct.pack(LAYOUT[layout][1], *values)


def unpack(layout: str, data: bytes) -> tuple[Any, ...] | None:
    """The values of a frame, or None when its length does not match the layout."""
    fmt = LAYOUT[layout][1]
    if len(data) != struct.calcsize(fmt):
        return None
    return struct.unpack(fmt, bytes(data))


@dataclass(frozen=True)
class CanNode:
    id: int
    joint: str | None = None  # None for the base
    unit: float = 1e-6
    gripper: bool = False

    @property
    def is_base(self) -> bool:
        return self.joint is None


@dataclass(frozen=True)
class BusConfig:
    master_node_id: int = 1
    sync_period: float = 0.01  # [s]
    master_heartbeat: float = 0.02  # [s]
    node_heartbeat_ms: int = 20
    consumer_timeout_ms: int = 100

    def consumer_heartbeat(self, timeout_ms: int | None = None) -> int:
        """The value of a node's 0x1016:01: it watches the master's heartbeat for ``timeout_ms``."""
        return (self.master_node_id << 16) | (self.consumer_timeout_ms if timeout_ms is None else timeout_ms)


@dataclass(frozen=True)
class CanMap:
    robot: str
    bus: BusConfig
    nodes: tuple[CanNode, ...]

    @property
    def joints(self) -> tuple[CanNode, ...]:
        return tuple(n for n in self.nodes if not n.is_base)

    @property
    def base(self) -> CanNode:
        return next(n for n in self.nodes if n.is_base)

    def by_joint(self, joint: str) -> CanNode:
        for n in self.nodes:
            if n.joint == joint:
                return n
        raise HalError(f"can map of {self.robot}: no node for joint {joint!r}")


def load_can_map(model: RobotModel) -> CanMap:
    """Read and check ``robots/<robot>/can_nodes.toml`` against the robot's joints."""
    path = robot_dir(model.name) / "can_nodes.toml"
    try:
        raw = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise HalError(f"{path}: cannot read the CAN node map: {e}") from e
    b = raw.get("bus", {})
    bus = BusConfig(
        master_node_id=int(b.get("master_node_id", 1)),
        sync_period=b.get("sync_period_ms", 10) / 1000.0,
        master_heartbeat=b.get("master_heartbeat_ms", 20) / 1000.0,
        node_heartbeat_ms=int(b.get("node_heartbeat_ms", 20)),
        consumer_timeout_ms=int(b.get("consumer_timeout_ms", 100)),
    )
    nodes = []
    for i, n in enumerate(raw.get("node", [])):
        nid = n.get("id")
        if not isinstance(nid, int) or not 1 <= nid <= 127 or nid == bus.master_node_id:
            raise HalError(f"{path}: [[node]] #{i}: id must be 1..127 and not the master's, got {nid!r}")
        if n.get("base"):
            nodes.append(CanNode(nid))
            continue
        joint = n.get("joint")
        if joint not in model.joint_names[3:]:
            raise HalError(f"{path}: [[node]] id {nid}: unknown joint {joint!r}; valid: {list(model.joint_names[3:])}")
        unit = float(n.get("unit", 1e-6))
        if not unit > 0:
            raise HalError(f"{path}: [[node]] id {nid}: unit must be > 0, got {unit}")
        nodes.append(CanNode(nid, joint, unit, bool(n.get("gripper", False))))
    ids = [n.id for n in nodes]
    if len(set(ids)) != len(ids):
        raise HalError(f"{path}: duplicate node ids in {ids}")
    missing = [j for j in model.joint_names[3:] if j not in {n.joint for n in nodes}]
    if missing or sum(n.is_base for n in nodes) != 1:
        raise HalError(f"{path}: needs one node per joint (missing {missing}) and exactly one base node")
    return CanMap(model.name, bus, tuple(nodes))
