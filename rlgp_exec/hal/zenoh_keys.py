"""The Zenoh key map of a robot (``robots/<robot>/zenoh_keys.toml``) and the session configuration.

Sessions are peers on loopback/LAN with multicast scouting off and no router: the robot side listens
on an endpoint (``tcp/127.0.0.1:7447``), the HAL connects to it. :func:`session_config` is the one
place a session's configuration is built: from a Zenoh configuration file (json5: TLS certificates under
``transport/link/tls``, ``access_control`` rules per certificate common name) when one is given, with the
endpoint given on the command line replacing the file's listen/connect endpoints. :func:`open_session`
opens it and turns Zenoh's start-up errors (busy port, bad endpoint, missing certificate) into one-line
:class:`HalError` messages. :func:`exact` is how every handler tells its own key from a wildcard that
merely intersects it.
"""

from __future__ import annotations

import json
import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from types import MappingProxyType
from typing import Any

import zenoh

from rlgp_exec.hal.types import HalError
from rlgp_exec.robots import robot_dir

__all__ = [
    "DEFAULT_ENDPOINT",
    "EXECUTIVE_LOST",
    "EXECUTIVE_SILENT",
    "ONE_OFF_COMMANDS",
    "KeyMap",
    "Topic",
    "control_publisher",
    "exact",
    "load_key_map",
    "open_session",
    "session_config",
]

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws", "unixsock-stream")  # what an endpoint may start with
_IP_PROTOCOLS = ("tcp", "tls", "udp", "quic", "ws")
# what a listening / connecting TLS session needs under transport/link/tls
_TLS_LISTEN = ("listen_certificate", "listen_private_key")
_TLS_CONNECT = ("root_ca_certificate",)
# the faults the robot side reports about the executive (on the faults key); its next command or keepalive
# clears them
EXECUTIVE_SILENT = "executive silent: no command or keepalive within 0.5 s: holding position"
EXECUTIVE_LOST = "executive lost: holding position"
ONE_OFF_COMMANDS = ("estop", "grasp", "gripper")  # sent once, not streamed: see control_publisher
_REQUIRED = ("joint_states", "odom", "runstop", "faults", "arm", "head", "gripper", "grasp", "cmd_vel", "estop")


@dataclass(frozen=True)
class Topic:
    name: str  # entry in the TOML ("arm")
    key: str  # full key expression, namespace included
    type: str  # ROS 2 message type
    direction: str  # "state" | "command"
    joints: tuple[str, ...] = ()
    ros2: str = ""  # the ROS 2 topic the bridge exposes as this key ("/hsrb/odom"); "" for an rlgp-only key


@dataclass(frozen=True)
class KeyMap:
    robot: str
    namespace: str
    topics: MappingProxyType[str, Topic]
    alive_robot: str
    alive_executive: str
    stats: str
    heartbeat: str  # the HAL's keepalive (std_msgs/Float64, a counter) while its last commands were at rest

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
        ros2 = t.get("ros2", "")
        # the Zenoh-ROS 2 bridge exposes "/<topic>" as the key "<topic>": a mismatch names a topic never bridged
        if ros2 and (not isinstance(ros2, str) or not ros2.startswith("/") or ros2[1:] != t["key"]):
            raise HalError(
                f"{path}: [keys.{name}].ros2 {ros2!r} is not the ROS 2 topic of key {t['key']!r} "
                f"(expected '/{t['key']}')"
            )
        topics[name] = Topic(name, _prefix(namespace, t["key"]), t["type"], t["dir"], tuple(t.get("joints", ())), ros2)
    live = raw.get("liveliness", {})
    return KeyMap(
        robot=robot,
        namespace=namespace,
        topics=MappingProxyType(topics),
        alive_robot=_prefix(namespace, live.get("robot", "rlgp/alive/robot")),
        alive_executive=_prefix(namespace, live.get("executive", "rlgp/alive/executive")),
        stats=_prefix(namespace, live.get("stats", "rlgp/stats")),
        heartbeat=_prefix(namespace, live.get("heartbeat", "rlgp/heartbeat/executive")),
    )


def exact(msg: Any, key: str) -> bool:
    """True when a sample's or query's key expression is ``key`` itself, not a wildcard (``rlgp/**``,
    ``**``) that Zenoh delivers because it intersects ``key``: only the exact key may command."""
    return str(msg.key_expr) == key


def _check_endpoint(ep: object) -> str:
    """``proto/host:port`` (host a name, an IPv4 or a bracketed IPv6 address), optional ``?``/``#`` tail."""
    if not isinstance(ep, str) or "/" not in ep:
        raise HalError(f"zenoh endpoint {ep!r} must look like tcp/127.0.0.1:7447")
    proto, addr = ep.split("/", 1)
    if proto not in PROTOCOLS:
        raise HalError(f"zenoh endpoint {ep!r}: unsupported protocol {proto!r}; valid: {list(PROTOCOLS)}")
    if proto in _IP_PROTOCOLS:
        m = re.fullmatch(r"(\[[0-9a-fA-F:.]+\]|[A-Za-z0-9.-]+):(\d{1,5})([?#].*)?", addr)
        if m is None or int(m.group(2)) > 65535:
            raise HalError(f"zenoh endpoint {ep!r} must look like {proto}/127.0.0.1:7447 (host:port, port <= 65535)")
    return ep


def _zenoh_message(e: BaseException) -> str:
    """Zenoh's error text on one line, without the Rust source locations it appends."""
    text = re.sub(r"\s+at /\S+?:\d+\.?", "", str(e))
    return " ".join(text.split()) or type(e).__name__


def session_config(
    *, listen: str | None = None, connect: str | None = None, config_file: str | Path | None = None
) -> Any:
    """A zenoh.Config: ``config_file`` (json5) if given, else peer mode; multicast and gossip scouting off
    either way (every link is an endpoint someone configured). ``listen`` / ``connect`` replace the file's
    endpoints: the session listens on exactly ``listen`` or connects to exactly ``connect``. Without
    either the file's endpoints stand (and a file is needed). A ``tls/`` endpoint needs the file's
    certificates: its absence is named here rather than left to a Zenoh error at open."""
    if listen is not None and connect is not None:
        raise HalError("zenoh session: give one of listen= or connect=, not both")
    if listen is None and connect is None and config_file is None:
        raise HalError("zenoh session: give listen= or connect= (an endpoint like tcp/127.0.0.1:7447) or a config file")
    ep = listen if listen is not None else connect
    if ep is not None:
        _check_endpoint(ep)
    if config_file is not None:
        try:
            Path(config_file).read_bytes()
        except OSError as e:
            raise HalError(f"zenoh config {config_file}: cannot read: {e.strerror}") from None
        try:
            c = zenoh.Config.from_file(str(config_file))
        except Exception as e:  # zenoh.ZError: unreadable, not json5, unknown field
            raise HalError(f"zenoh config {config_file}: {_zenoh_message(e)}") from None
    else:
        c = zenoh.Config()
        c.insert_json5("mode", '"peer"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("scouting/gossip/enabled", "false")
    if ep is not None:
        c.insert_json5("listen/endpoints", json.dumps([listen] if listen else []))
        c.insert_json5("connect/endpoints", json.dumps([connect] if connect else []))
    _check_tls(c, config_file)
    return c


def _check_tls(c: Any, config_file: str | Path | None) -> None:
    tls = json.loads(c.get_json("transport/link/tls"))
    for role, needed in (("listen", _TLS_LISTEN), ("connect", _TLS_CONNECT)):
        eps = json.loads(c.get_json(f"{role}/endpoints"))
        eps = eps if isinstance(eps, list) else [e for v in eps.values() for e in v]  # per-mode form
        for ep in eps:
            if str(ep).startswith("tls/"):
                missing = [f for f in needed if not tls.get(f)]
                if missing:
                    where = f"zenoh config {config_file}" if config_file else "no --zenoh-config given"
                    raise HalError(f"zenoh endpoint {ep!r} is TLS but transport/link/tls lacks {missing} ({where})")


def control_publisher(session: Any, key: str, must_arrive: bool = False) -> Any:
    """A publisher for the robot's state and commands: at real-time priority, sent at once (not batched).
    Camera frames share the link at a lower priority: at the default priority a frame's fragments ahead of a
    joint state held it up past the state watchdog. A stream (states, setpoints, keepalives) drops a sample
    when the link is congested, as the next one replaces it; a one-off command (``must_arrive``: the e-stop,
    the gripper) waits for room instead, as nothing streams it (the e-stop is sent again only when the
    robot's state does not confirm it)."""
    congestion = zenoh.CongestionControl.BLOCK if must_arrive else zenoh.CongestionControl.DROP
    return session.declare_publisher(
        key, priority=zenoh.Priority.REAL_TIME, express=True, congestion_control=congestion
    )


def open_session(config: Any, what: str) -> Any:
    """``zenoh.open(config)``; a failure (port in use, bad address, unreadable certificate) is a HalError
    naming ``what`` and Zenoh's reason in one line."""
    try:
        return zenoh.open(config)
    except Exception as e:  # zenoh.ZError
        raise HalError(f"{what}: {_zenoh_message(e)}") from None
