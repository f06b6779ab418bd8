"""The simulated robot server: PyBullet physics (DIRECT) behind the robot's own wire interfaces.

    python -m rlgp_exec.sim.robot_server --robot hsr --transport zenoh [--scene PATH] [--endpoint tcp/127.0.0.1:7447]
    python -m rlgp_exec.sim.robot_server --robot hsr --transport can --can-interface socketcan --can-channel vcan0

Zenoh: the keys and CDR payloads of ``robots/<robot>/zenoh_keys.toml`` (what the Zenoh-ROS 2 bridge
exposes on the real HSR), joint states / odometry / run-stop at ``--rate`` Hz (100 by default), a
liveliness token for presence and a ``rlgp/stats`` queryable with the reject counters. The server listens
on ``--endpoint``; clients connect to it. CAN: the CANopen node set of ``robots/<robot>/can_nodes.toml``
(see ``sim/robot_server_can.py``) on a python-can bus.

Every command is decoded defensively and checked against the robot's limits again here; a bad one is
rejected, counted, logged, and moves nothing. A sample acts only when its key expression is exactly the
command's key: a put on a wildcard (``hsrb/**``, ``**``) that Zenoh delivers to every subscriber it
intersects is rejected ("wildcard"). The physics runs in real time (stepped every period).

Its own deadline on the executive, not the transport's lease (10 s): once commanded (an arm setpoint or
a base twist accepted), the server expects a command or an executive keepalive (``rlgp/heartbeat/
executive``) at least every ``COMMAND_DEADLINE_S``; when none comes it holds (base twist zero, arm at its
measured position) and reports the fault ``executive silent`` until commands or keepalives resume. The
"executive lost" fault (its liveliness token gone) is likewise cleared by a command or keepalive, not
by a token, which any peer can declare.

Releasing the e-stop (``rlgp/estop`` false) is a deliberate act: the executive sends it only on an
operator's confirmed ``rearm``. Who may send it, and any command, is the Zenoh configuration's business
(``--zenoh-config``): mutual TLS on the endpoint and ``access_control`` rules allowing the command keys to
the executive's certificate only.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time
from collections import Counter
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
import zenoh

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.world import DRAWER_SUFFIX, MOCAP_KEY
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.sim_physics import SimRobot
from rlgp_exec.hal.types import GripperCommand, JointSetpoint
from rlgp_exec.hal.validate import CommandLimits, RejectCounter
from rlgp_exec.hal.zenoh_keys import (
    DEFAULT_ENDPOINT,
    control_publisher,
    exact,
    load_key_map,
    open_session,
    session_config,
)
from rlgp_exec.hal.zenoh_keys import EXECUTIVE_LOST as LOST
from rlgp_exec.hal.zenoh_keys import EXECUTIVE_SILENT as SILENT
from rlgp_exec.scene import load_scene
from rlgp_exec.sim.logs import configure_logging
from rlgp_exec.sim.realtime import RealTimeLoop

__all__ = ["RealTimeLoop", "ZenohRobotServer", "build_sim", "main"]

log = logging.getLogger("rlgp_exec.sim.robot_server")

PUSH_KEY = "rlgp/sim/push"  # sim only: JSON {"object", "dx", "dy"} moves an object (a test's "someone bumped it")
MOCAP_EVERY = 5  # ticks between object-pose messages (20 Hz at 100 Hz)
COMMAND_DEADLINE_S = 0.5  # [s] commanded, and no command or keepalive for this long: hold


def _ns(namespace: str, key: str) -> str:
    return f"{namespace}/{key}" if namespace else key


class ZenohRobotServer:
    """The robot side of the zenoh backend, driving a :class:`SimRobot`."""

    def __init__(
        self,
        sim: SimRobot,
        endpoint: str | None = DEFAULT_ENDPOINT,
        namespace: str = "",
        rate_hz: float = 100.0,
        config_file: str | None = None,
        realtime: bool = False,
    ) -> None:
        self.sim = sim
        self.keys = load_key_map(sim.model.name, namespace)
        self.endpoint = endpoint  # None: the config file's listen endpoints
        self.config_file = config_file
        self.limits = CommandLimits(sim.model)
        self.period = 1.0 / rate_hz
        self.rejects = RejectCounter("robot_server[zenoh]")
        self.accepted: Counter[str] = Counter()
        self.lock = threading.Lock()
        self.loop = RealTimeLoop(self.period, self.tick, "zenoh-robot", realtime)
        self._session: Any = None
        self._pubs: dict[str, Any] = {}
        self._decls: list[Any] = []
        self._token: Any = None
        self._executive_seen = False
        self._stopping = False
        self._ticks = 0
        self._faults_sent: tuple[str, ...] = ()
        self._commanded = False  # a motion command was accepted: the deadline runs
        self._last_heard = -float("inf")  # [s, monotonic] the last command or keepalive
        self.holds: Counter[str] = Counter()  # holds for a silent / lost executive

    # ------------------------------------------------------------------ set-up
    def start(self) -> None:
        self._stopping = False
        rc.prepare()
        config = session_config(listen=self.endpoint, config_file=self.config_file)
        s = open_session(config, f"robot server: cannot listen on {self.endpoint or self.config_file}")
        self._session = s
        try:
            self._declare(s)
        except Exception:
            self.stop()  # a half-declared session is closed, not left running
            raise
        self.loop.start()
        log.info(
            "zenoh robot server (%s) listening on %s, namespace %r",
            self.sim.model.name,
            self.endpoint or self.config_file,
            self.keys.namespace,
        )

    def _declare(self, s: Any) -> None:
        k = self.keys
        for name in ("joint_states", "odom", "runstop", "faults"):
            self._pubs[name] = control_publisher(s, k[name].key)
        handlers: dict[str, Callable[[bytes, str], None]] = {
            "cmd_vel": self._cmd_vel,
            "grasp": self._grasp,
            "estop": self._estop,
            "gripper": self._gripper,
            "heartbeat": self._heartbeat,
        }
        for t in k.joint_topics():
            handlers[t.name] = self._joint_trajectory
        for name, fn in handlers.items():
            key = k.heartbeat if name == "heartbeat" else k[name].key
            self._decls.append(s.declare_subscriber(key, self._guard(name, key, fn)))
        self._decls.append(s.liveliness().declare_subscriber(k.alive_executive, self._on_executive, history=True))
        self._decls.append(s.declare_queryable(k.stats, self._on_stats))
        if self.sim.objects:  # the simulated world's object poses, as a motion-capture system would send them
            self._pubs["mocap"] = s.declare_publisher(_ns(k.namespace, MOCAP_KEY))
            push = _ns(k.namespace, PUSH_KEY)
            self._decls.append(s.declare_subscriber(push, self._guard("push", push, self._push)))
        self._token = s.liveliness().declare_token(k.alive_robot)

    def stop(self) -> None:
        self._stopping = True  # samples still in flight are dropped: the physics closes next
        self.loop.stop()
        if self._session is not None:
            try:
                if self._token is not None:
                    self._token.undeclare()
            except Exception as e:
                log.debug("undeclare failed: %s", e)
            self._session.close()
            self._session = None

    # ------------------------------------------------------------------ loop
    def tick(self) -> None:
        with self.lock:
            if self._commanded and time.monotonic() - self._last_heard > COMMAND_DEADLINE_S:
                self._hold_for(SILENT, "silent")
            self.sim.step(self.period)
            st = self.sim.state()
        self._ticks += 1
        self._pubs["joint_states"].put(rc.encode_joint_state(st.stamp, st.names, st.q, st.dq))
        self._pubs["odom"].put(rc.encode_odometry(st.stamp, *st.base, *st.base_velocity))
        self._pubs["runstop"].put(rc.encode_bool(st.estopped))
        if self._ticks % 10 == 0 or st.faults != self._faults_sent:  # a change goes out at once
            self._pubs["faults"].put(rc.encode_string("\n".join(st.faults)))
            self._faults_sent = st.faults
        if "mocap" in self._pubs and self._ticks % MOCAP_EVERY == 0:
            with self.lock:
                poses = {n: self.sim.object_pose(n) for n in self.sim.objects}
                poses.update({f"{c}{DRAWER_SUFFIX}": self.sim.drawer_pose(c) for c in self.sim.cabinets})
            self._pubs["mocap"].put(rc.encode_transforms(st.stamp, poses))

    # ------------------------------------------------------------------ commands
    def _guard(self, topic: str, key: str, fn: Callable[[bytes, str], None]) -> Callable[[Any], None]:
        def cb(sample: Any) -> None:
            if self._stopping:
                return
            if not exact(sample, key):
                self.rejects.reject("wildcard", f"{topic}: sample on {sample.key_expr}, not {key}")
                return
            try:
                fn(sample.payload.to_bytes(), topic)
            except Exception as e:  # never let a payload kill the server
                self.rejects.reject("internal", f"{topic}: {type(e).__name__}: {e}")
                log.exception("robot_server: handler for %s failed", topic)

        return cb

    def _ok(self, topic: str) -> None:
        self.accepted[topic] += 1

    def _heard(self, motion: bool) -> None:
        """A command or keepalive from the executive (lock held): the deadline restarts, the executive's
        faults clear; a motion command starts the deadline."""
        self._last_heard = time.monotonic()
        self._commanded = self._commanded or motion
        for f in (SILENT, LOST):
            if f in self.sim.faults:
                self.sim.faults.remove(f)
                log.warning("robot_server: executive back: %r cleared", f)

    def _hold_for(self, fault: str, kind: str) -> None:
        """Hold (lock held): the arm at its measured position, the base stopped; report ``fault`` once.
        The deadline stops until the next motion command."""
        st = self.sim.state()
        self.sim.set_joint_targets(JointSetpoint(self.limits.setpoint_names, st.positions(self.limits.setpoint_names)))
        self.sim.set_base_velocity(0.0, 0.0, 0.0)
        self._commanded = False
        if fault not in self.sim.faults:
            self.sim.faults.append(fault)
            self.holds[kind] += 1
            log.warning("robot_server: %s", fault)

    def _decode(self, payload: bytes, typename: str, topic: str) -> Any:
        """The message, or None (rejected and counted)."""
        m = rc.decode(payload, typename)
        if isinstance(m, rc.Rejected):
            self.rejects.reject(m.key, f"{topic}: {m.reason}")
            return None
        return m

    def _heartbeat(self, payload: bytes, topic: str) -> None:
        if self._decode(payload, "std_msgs/msg/Float64", topic) is None:
            return
        with self.lock:
            self._heard(motion=False)
        self._ok(topic)

    def _joint_trajectory(self, payload: bytes, topic: str) -> None:
        sp = rc.parse_trajectory(payload)
        if isinstance(sp, rc.Rejected):
            self.rejects.reject(sp.key, f"{topic}: {sp.reason}")
            return
        allowed = self.keys[topic].joints
        wrong = [n for n in sp.names if n not in allowed]
        if wrong:
            self.rejects.reject(
                "unknown_joint", f"{topic}: joint(s) {wrong} not on this controller; valid: {list(allowed)}"
            )
            return
        reason = self.limits.check_setpoint(sp)
        if reason:
            self.rejects.reject("limits", f"{topic}: {reason}")
            return
        with self.lock:
            self._heard(motion=True)
            if self.sim.set_joint_targets(sp):
                self._ok(topic)
            else:
                self.rejects.reject("estopped", f"{topic}: ignored while e-stopped")

    def _gripper(self, payload: bytes, topic: str) -> None:
        sp = rc.parse_trajectory(payload)
        if isinstance(sp, rc.Rejected):
            self.rejects.reject(sp.key, f"{topic}: {sp.reason}")
            return
        g = self.limits.gripper_joint
        if sp.names != (g,):
            self.rejects.reject("unknown_joint", f"{topic}: expected exactly [{g!r}], got {list(sp.names)}")
            return
        i = self.limits.names.index(g)
        if not (self.limits.lower[i] <= sp.q[0] <= self.limits.upper[i]):
            self.rejects.reject(
                "limits", f"{topic}: {g}={sp.q[0]} not in [{self.limits.lower[i]}, {self.limits.upper[i]}]"
            )
            return
        with self.lock:
            if self.sim.gripper_to(float(sp.q[0])):
                self._ok(topic)
            else:
                self.rejects.reject("estopped", f"{topic}: ignored while e-stopped")

    def _grasp(self, payload: bytes, topic: str) -> None:
        m = self._decode(payload, "std_msgs/msg/Float64", topic)
        if m is None:
            return
        reason = self.limits.check_grasp_force(m.data)
        if reason:
            self.rejects.reject("limits", f"{topic}: {reason}")
            return
        with self.lock:
            if self.sim.gripper(GripperCommand.grasp(float(m.data))):
                self._ok(topic)
            else:
                self.rejects.reject("estopped", f"{topic}: ignored while e-stopped")

    def _cmd_vel(self, payload: bytes, topic: str) -> None:
        v = rc.parse_twist(payload)
        if isinstance(v, rc.Rejected):
            self.rejects.reject(v.key, f"{topic}: {v.reason}")
            return
        reason = self.limits.check_base_velocity(*v)
        if reason:
            self.rejects.reject("limits", f"{topic}: {reason}")
            return
        with self.lock:
            self._heard(motion=True)
            if self.sim.set_base_velocity(*v):
                self._ok(topic)
            else:
                self.rejects.reject("estopped", f"{topic}: ignored while e-stopped")

    def _estop(self, payload: bytes, topic: str) -> None:
        m = self._decode(payload, "std_msgs/msg/Bool", topic)
        if m is None:
            return
        with self.lock:
            changed = bool(m.data) != self.sim.estopped
            self.sim.estop(bool(m.data))
            if m.data:
                self._commanded = False  # e-stopped it holds by itself: no deadline until commanded again
        self._ok(topic)
        if changed:  # an executive re-sends its e-stop until it sees it engaged: one line per change
            log.warning("robot_server: e-stop %s", "ENGAGED" if m.data else "released")

    def _push(self, payload: bytes, topic: str) -> None:
        """Sim only: move an object on its support by (dx, dy) [m] — someone bumped it. JSON payload
        {"object": name, "dx": m, "dy": m}; |d| <= 0.3 m; a held object cannot be pushed."""
        try:
            req = json.loads(payload)
            name, dx, dy = req["object"], float(req["dx"]), float(req["dy"])
        except (ValueError, KeyError, TypeError) as e:
            self.rejects.reject("malformed", f"{topic}: {type(e).__name__}: {e}")
            return
        with self.lock:
            if name not in self.sim.objects:
                self.rejects.reject("unknown_object", f"{topic}: {name!r}; valid: {sorted(self.sim.objects)}")
                return
            if not (np.isfinite(dx) and np.isfinite(dy) and np.hypot(dx, dy) <= 0.3) or name == self.sim.held:
                self.rejects.reject("invalid", f"{topic}: cannot push {name!r} by ({dx}, {dy})")
                return
            self.sim.push_object(name, dx, dy)
        self._ok(topic)
        log.warning("robot_server: pushed %s by (%.3f, %.3f) m", name, dx, dy)

    def _on_executive(self, sample: Any) -> None:
        if self._stopping:
            return
        if not exact(sample, self.keys.alive_executive):
            self.rejects.reject("wildcard", f"liveliness on {sample.key_expr}, not {self.keys.alive_executive}")
            return
        with self.lock:
            if sample.kind == zenoh.SampleKind.PUT:  # presence only: a token clears no fault (anyone can declare one)
                self._executive_seen = True
                log.info("robot_server: executive present")
            elif self._executive_seen:
                self._hold_for(LOST, "lost")

    def stats(self) -> dict[str, Any]:
        return {
            "rejected": self.rejects.counts(),
            "rejected_total": self.rejects.total,
            "accepted": dict(self.accepted),
            "ticks": self._ticks,
            "holds": dict(self.holds),
            "sim_time": self.sim.time,
            "loop_period_err_ms_p99": self.loop.p99_ms(),
            "loop_policy": self.loop.grant.policy,
        }

    def _on_stats(self, query: Any) -> None:
        if exact(query, self.keys.stats):
            query.reply(self.keys.stats, json.dumps(self.stats()).encode())


def build_sim(robot: str, scene_path: str | None) -> SimRobot:
    scene = None
    if scene_path:
        scene = load_scene(scene_path)
        if scene.robot.name != robot:
            raise RlgpError(f"--scene {scene_path} is for robot {scene.robot.name!r}, not --robot {robot!r}")
    return SimRobot(robot, scene)


def _parser() -> argparse.ArgumentParser:
    ap = argparse.ArgumentParser(prog="python -m rlgp_exec.sim.robot_server", description=__doc__.split("\n\n")[0])
    ap.add_argument("--robot", choices=["hsr", "pr2"], required=True)
    ap.add_argument("--transport", choices=["zenoh", "can"], required=True)
    ap.add_argument("--scene", help="a scene TOML (default: the robot alone on a floor)")
    ap.add_argument("--endpoint", help=f"zenoh: endpoint to listen on (default {DEFAULT_ENDPOINT}, or the config's)")
    ap.add_argument(
        "--zenoh-config", help="zenoh: a json5 configuration (TLS, access control); --endpoint replaces its listen"
    )
    ap.add_argument("--namespace", default="", help="zenoh: key prefix (the bridge's namespace)")
    ap.add_argument("--can-interface", default="socketcan", help="can: python-can interface (socketcan, udp_multicast)")
    ap.add_argument("--can-channel", default="vcan0", help="can: python-can channel")
    ap.add_argument("--rate", type=float, default=100.0, help="state publishing / physics rate [Hz]")
    ap.add_argument(
        "--realtime",
        action="store_true",
        help="physics loop under SCHED_FIFO (a robot PC of its own; beside the executive it starves this "
        "server's message threads)",
    )
    ap.add_argument("--duration", type=float, default=0.0, help="stop after this many seconds (0: run until killed)")
    ap.add_argument("-v", "--verbose", action="count", default=0)
    return ap


def main(argv: Sequence[str] | None = None) -> int:
    """Run the server until SIGINT/SIGTERM (or --duration). Exit 0 on a clean stop, 2 on bad input."""
    args = _parser().parse_args(None if argv is None else list(argv))
    configure_logging(args.verbose)
    if args.transport == "can" and args.robot != "hsr":
        print(f"rlgp_exec.sim.robot_server: no CANopen node map for robot {args.robot!r}; valid: hsr", file=sys.stderr)
        return 2
    if not args.rate > 0:
        print(f"rlgp_exec.sim.robot_server: --rate must be > 0, got {args.rate}", file=sys.stderr)
        return 2
    endpoint = args.endpoint or (None if args.zenoh_config else DEFAULT_ENDPOINT)
    sim = None
    try:
        if args.transport == "zenoh":  # a bad endpoint or configuration is named before the physics loads
            session_config(listen=endpoint, config_file=args.zenoh_config)
        sim = build_sim(args.robot, args.scene)
        server: Any
        if args.transport == "zenoh":
            server = ZenohRobotServer(sim, endpoint, args.namespace, args.rate, args.zenoh_config, args.realtime)
        else:
            # local: sim.robot_server_can brings python-can
            from rlgp_exec.sim.robot_server_can import CanRobotServer, open_bus

            bus = open_bus(args.can_interface, args.can_channel)
            server = CanRobotServer(sim, bus, rate_hz=args.rate, realtime=args.realtime)
        server.start()
    except RlgpError as e:
        if sim is not None:
            sim.close()
        print(f"rlgp_exec.sim.robot_server: error: {e}", file=sys.stderr)
        return 2
    done = threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: done.set())
    print(f"robot_server ready: {args.robot} over {args.transport}", flush=True)
    try:
        done.wait(args.duration if args.duration > 0 else None)
    finally:
        server.stop()
        sim.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
