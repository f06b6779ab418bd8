"""The Zenoh key map of a robot (``robots/<robot>/zenoh_keys.toml``) and the session configuration.

Sessions are peers on loopback/LAN with multicast scouting off and no router: the robot side listens
on an endpoint (``tcp/127.0.0.1:7447``), the HAL connects to it.
"""

from __future__ import annotations

import json
import tomllib
from dataclasses import dataclass
from types import MappingProxyType
from typing import Any

from rlgp_exec.hal.types import HalError
from robots import robot_dir

__all__ = ["DEFAULT_ENDPOINT", "KeyMap", "Topic", "load_key_map", "session_config"]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
_REQUIRED = ("joint_states", "odom", "runstop", "faults", "arm", "head", "gripper", "grasp", "cmd_vel", "estop")


@dataclass(frozen=True)
class Topic:
    name: str  # entry in the TOML ("arm")
    key: str  # full key expression, namespace included
    type: str  # ROS 2 message type
    direction: str  # "state" | "command"
    joints: tuple[str, ...] = ()


@dataclass(frozen=True)
class KeyMap:
    robot: str
    namespace: str
    topics: MappingProxyType[str, Topic]
    alive_robot: str
    alive_executive: str
    stats: str

    def __getitem__(self, name: str) -> Topic:
        try:
            return self.topics[name]
        except KeyError:
            raise HalError(f"zenoh key map of {self.robot}: no topic {name!r}; valid: {list(self.topics)}") from None

    def joint_topics(self) -> list[Topic]:
        """The command topics that carry joint trajectories for setpoints (not the gripper)."""
        return [t for t in self.topics.values() if t.joints and t.name != "gripper"]


def _prefix(ns: str, key: str) -> str:
    ns = ns.strip("/")
    return f"{ns}/{key}" if ns else key


def load_key_map(robot: str = "hsr", namespace: str = "") -> KeyMap:
    """The key map of ``robot`` under ``namespace`` (no leading/trailing '/'; '' for none)."""
    if any(c in namespace for c in "*$?#"):
        raise HalError(f"zenoh namespace {namespace!r} must not contain wildcards (* $ ? #)")
    try:
        path = robot_dir(robot) / "zenoh_keys.toml"
    except KeyError as e:
        raise HalError(str(e)) from None
    try:
        raw: dict[str, Any] = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as e:
        raise HalError(f"{path}: cannot read the zenoh key map: {e}") from e
    keys = raw.get("keys", {})
    missing = [k for k in _REQUIRED if k not in keys]
    if missing:
        raise HalError(f"{path}: [keys] lacks {missing}")
    topics = {}
    for name, t in keys.items():
        for f in ("key", "type", "dir"):
            if f not in t:
                raise HalError(f"{path}: [keys.{name}] lacks '{f}'")
        if t["dir"] not in ("state", "command"):
            raise HalError(f"{path}: [keys.{name}].dir must be 'state' or 'command', got {t['dir']!r}")
        topics[name] = Topic(name, _prefix(namespace, t["key"]), t["type"], t["dir"], tuple(t.get("joints", ())))
    live = raw.get("liveliness", {})
    return KeyMap(
        robot=robot,
        namespace=namespace,
        topics=MappingProxyType(topics),
        alive_robot=_prefix(namespace, live.get("robot", "rlgp/alive/robot")),
        alive_executive=_prefix(namespace, live.get("executive", "rlgp/alive/executive")),
        stats=_prefix(namespace, live.get("stats", "rlgp/stats")),
    )


def session_config(*, listen: str | None = None, connect: str | None = None) -> Any:
    """A zenoh.Config: peer mode, multicast scouting off, listening on or connecting to one endpoint."""
    import zenoh

    if (listen is None) == (connect is None):
        raise HalError("zenoh session: give exactly one of listen= or connect= (an endpoint like tcp/127.0.0.1:7447)")
    ep = listen or connect
    if not isinstance(ep, str) or "/" not in ep:
        raise HalError(f"zenoh endpoint {ep!r} must look like tcp/127.0.0.1:7447")
    c = zenoh.Config()
    c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
    c.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    return c
