"""The ``zenoh`` backend: the robot's ROS 2 topics through the Zenoh-ROS 2 bridge (or the simulated robot
server), CDR payloads, peer session connecting to one endpoint. Keys: ``robots/<robot>/zenoh_keys.toml``.

State arrives on three keys (joint_states, odom, runstop) plus faults; every payload is decoded
defensively and rejected (counted in :attr:`rejects`, logged) when malformed, of the wrong type, non-finite
or naming joints the robot does not have. The heartbeat is the robot's liveliness token together with
fresh joint states and odometry (wall-clock age below ``heartbeat_timeout``). A state sample is taken
only from exactly its key: a put on a wildcard (``hsrb/**``) that intersects it is rejected.

The robot side holds when it hears nothing from the executive for 0.5 s while commanded (its own
deadline, not the transport's lease). Commands stream at the control rate while the robot moves; while the
last commands were at rest (planning, idle, faulted, a single position target) this backend sends a
keepalive on ``rlgp/heartbeat/executive`` every ``KEEPALIVE_S``. Not after a moving command (feed-forward
joint velocity, a base twist above ``REST_BASE``): a control loop that hangs mid-motion, this thread
still alive, must let the robot's deadline stop it, not mask it.

The e-stop is confirmed, not assumed: from ``estop()`` until an explicit ``rearm()`` the same thread checks
every ``KEEPALIVE_S`` that the robot's run-stop reports engaged. When no run-stop sample saying engaged has
arrived within ``ESTOP_CONFIRM_S`` (of the e-stop, or of the last one that did) -- a lost sample, a robot
server restarted un-stopped, a robot not heard at all -- it sends the e-stop again, every ``KEEPALIVE_S``,
until one does (:meth:`ZenohBackend.estop_status`). The re-send and ``rearm()`` share a lock, so a
release is never followed by a late re-send that latches the robot again.
"""

from __future__ import annotations

import logging
import threading
import time
from typing import Any

import numpy as np
import zenoh

from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.interface import RobotInterface
from rlgp_exec.hal.types import EstopStatus, GripperAction, GripperCommand, HalError, JointSetpoint, RobotState
from rlgp_exec.hal.zenoh_keys import (
    DEFAULT_ENDPOINT,
    EXECUTIVE_LOST,
    EXECUTIVE_SILENT,
    ONE_OFF_COMMANDS,
    control_publisher,
    exact,
    load_key_map,
    open_session,
    session_config,
)
from rlgp_exec.robot import load_robot

__all__ = ["ZenohBackend"]

log = logging.getLogger(__name__)

KEEPALIVE_S = 0.1  # [s] keepalive period at rest: 5 per robot-side deadline (0.5 s)
ACTIVATE_WAIT_S = 0.5  # [s] at most, for the robot to clear its faults about this executive on activate
REST_BASE = 0.05  # [m/s, rad/s] a twist below this is a hold (the executive's odometry correction at rest)
REST_JOINT = 1e-6  # [rad/s, m/s] feed-forward velocity below which a setpoint is a hold
# [s] the run-stop must report engaged within this of the e-stop (and keep reporting it), else the e-stop is
# sent again: 30 run-stop samples at 100 Hz, above the heartbeat timeout (0.25 s) a state gap may last
ESTOP_CONFIRM_S = 0.3


class ZenohBackend(RobotInterface):
    backend = "zenoh"

    def __init__(
        self,
        robot: str = "hsr",
        endpoint: str | None = None,
        namespace: str = "",
        heartbeat_timeout: float = 0.25,
        control_period: float = 0.01,
        config_file: str | None = None,
    ) -> None:
        super().__init__(load_robot(robot), heartbeat_timeout)
        self.keys = load_key_map(robot, namespace)
        # no endpoint: the config file's connect endpoints, else the default one
        self.endpoint = endpoint if endpoint is not None or config_file is not None else DEFAULT_ENDPOINT
        self.config_file = config_file  # json5: TLS certificates, access control
        self._keepalive_stop = threading.Event()
        self._keepalive: threading.Thread | None = None
        self.keepalives = 0  # sent
        self._moving = {"arm": False, "base": False}  # the last setpoint / twist sent was a motion
        self.control_period = float(control_period)
        self._lock = threading.Lock()
        self._session: Any = None
        self._decls: list[Any] = []
        self._pubs: dict[str, Any] = {}
        self._token: Any = None
        self._robot_alive = False
        self._q = dict.fromkeys(self.joint_names, np.nan)
        self._dq = dict.fromkeys(self.joint_names, 0.0)
        self._js_stamp = 0.0
        self._js_wall = -np.inf
        self._odom: tuple[tuple[float, float, float], tuple[float, float, float]] | None = None
        self._odom_wall = -np.inf
        self._runstop = False
        self._runstop_engaged_wall = -np.inf  # [s, monotonic] the last run-stop sample reporting engaged arrived
        # the e-stop's confirmation; the lock orders a re-send before a rearm's release, never after it
        self._estop_lock = threading.Lock()
        self._estop_engaged = False  # estop() sent it, no rearm() since
        self._estop_since = -np.inf  # [s, monotonic] it was last commanded by estop()
        self._estop_resending = False  # unconfirmed past the deadline (logged once per episode)
        self._estop_episode_resends = 0
        self.estop_resends = 0  # e-stops sent again, unconfirmed (since configure)
        self._faults: tuple[str, ...] = ()
        self.received = 0  # accepted state messages

    # ------------------------------------------------------------------ lifecycle hooks
    def _on_configure(self) -> None:
        rc.prepare()
        config = session_config(connect=self.endpoint, config_file=self.config_file)
        s = open_session(config, f"zenoh: cannot connect to {self.endpoint or self.config_file}")
        self._session = s
        try:
            self._declare(s)
        except Exception:
            self._on_shutdown()  # a half-declared session is closed, not left running
            raise
        log.info("zenoh: connected to %s (namespace %r)", self.endpoint or self.config_file, self.keys.namespace)

    def _declare(self, s: Any) -> None:
        k = self.keys
        self._decls += [
            s.declare_subscriber(k["joint_states"].key, self._exact("joint_states", self._on_joint_states)),
            s.declare_subscriber(k["odom"].key, self._exact("odom", self._on_odom)),
            s.declare_subscriber(k["runstop"].key, self._exact("runstop", self._on_runstop)),
            s.declare_subscriber(k["faults"].key, self._exact("faults", self._on_faults)),
            s.liveliness().declare_subscriber(k.alive_robot, self._on_alive, history=True),
        ]
        for t in k.topics.values():
            if t.direction == "command":
                self._pubs[t.name] = control_publisher(s, t.key, must_arrive=t.name in ONE_OFF_COMMANDS)
        self._pubs["heartbeat"] = control_publisher(s, k.heartbeat)
        self._token = s.liveliness().declare_token(k.alive_executive)
        self._keepalive_stop.clear()
        self._keepalive = threading.Thread(target=self._keepalive_loop, name="zenoh-keepalive", daemon=True)
        self._keepalive.start()

    def _exact(self, topic: str, fn: Any) -> Any:
        key = self.keys[topic].key

        def cb(sample: Any) -> None:
            if exact(sample, key):
                fn(sample)
            else:
                self.rejects.reject("wildcard", f"{topic}: sample on {sample.key_expr}, not {key}")

        return cb

    def _keepalive_loop(self) -> None:
        while not self._keepalive_stop.wait(KEEPALIVE_S):
            self._confirm_estop()
            if not any(self._moving.values()):  # else the command stream is the heartbeat; its silence must show
                self._send_keepalive()

    def _send_keepalive(self) -> None:
        try:
            self._pubs["heartbeat"].put(rc.encode_float64(float(self.keepalives + 1)))
            self.keepalives += 1
        except Exception as e:  # the session is closing
            log.debug("zenoh: keepalive: %s", e)

    def _estop_confirmed(self, now: float) -> bool:
        """The run-stop reports engaged, in a sample that came after the e-stop and within the deadline."""
        with self._lock:
            last = self._runstop_engaged_wall
            return self._runstop and last >= self._estop_since and now - last <= ESTOP_CONFIRM_S

    def _confirm_estop(self) -> None:
        """While the e-stop is commanded: send it again when the robot's state does not confirm it."""
        with self._estop_lock:
            if not self._estop_engaged:
                return
            now = time.monotonic()
            if self._estop_confirmed(now):
                if self._estop_resending:
                    log.warning(
                        "zenoh: the robot reports its run-stop engaged, after %d e-stop re-send(s)",
                        self._estop_episode_resends,
                    )
                self._estop_resending, self._estop_episode_resends = False, 0
                return
            with self._lock:
                heard = max(self._estop_since, self._runstop_engaged_wall)
                runstop, state_age = self._runstop, now - self._js_wall
            if now - heard <= ESTOP_CONFIRM_S:
                return  # the robot has until the deadline to report it
            if not self._estop_resending:
                log.warning(
                    "zenoh: the robot has not reported its run-stop engaged for %.2f s (run-stop %s, joint "
                    "state %.2f s old): sending the e-stop again every %.1f s until it does",
                    now - heard,
                    "engaged" if runstop else "released",
                    state_age,
                    KEEPALIVE_S,
                )
                self._estop_resending = True
            try:
                self._put("estop", rc.encode_bool(True))
            except Exception as e:  # the session is closing; the next period tries again
                log.debug("zenoh: e-stop re-send: %s", e)
                return
            self.estop_resends += 1
            self._estop_episode_resends += 1

    def estop_status(self) -> EstopStatus:
        with self._estop_lock:
            engaged = self._estop_engaged
        return EstopStatus(engaged, engaged and self._estop_confirmed(time.monotonic()), self.estop_resends)

    def _on_activate(self) -> None:
        """Nothing moves yet: keepalives again (a fault may have stopped a stream without its hold), and the
        robot's faults about this executive cleared before the first command."""
        self._moving = dict.fromkeys(self._moving, False)
        self._send_keepalive()
        end = time.monotonic() + ACTIVATE_WAIT_S
        while time.monotonic() < end:
            with self._lock:
                if not {EXECUTIVE_SILENT, EXECUTIVE_LOST} & set(self._faults):
                    return
            time.sleep(0.005)
        log.warning("zenoh: the robot still reports %s after %.1f s", self._faults, ACTIVATE_WAIT_S)

    def _on_shutdown(self) -> None:
        self._keepalive_stop.set()
        if self._keepalive is not None:
            self._keepalive.join(timeout=1.0)
            self._keepalive = None
        if self._session is None:
            return
        try:
            if self._token is not None:
                self._token.undeclare()
            for d in self._decls:
                d.undeclare()
            for p in self._pubs.values():
                p.undeclare()
        except Exception as e:  # the session may already be broken; closing is what matters
            log.debug("zenoh: undeclare during shutdown failed: %s", e)
        self._session.close()
        self._session = None

    @property
    def session(self) -> Any:
        """The open Zenoh session (None unless configured), for other subscribers on the same link."""
        return self._session

    def wait_for_robot(self, timeout: float = 10.0) -> bool:
        """Block until the heartbeat is ok (robot present, fresh state) or ``timeout`` [s] passes."""
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            if self.heartbeat_ok():
                return True
            time.sleep(0.01)
        return False

    # ------------------------------------------------------------------ incoming
    def _on_alive(self, sample: Any) -> None:
        if not exact(sample, self.keys.alive_robot):
            self.rejects.reject("wildcard", f"robot liveliness on {sample.key_expr}, not {self.keys.alive_robot}")
            return
        alive = sample.kind == zenoh.SampleKind.PUT
        with self._lock:
            self._robot_alive = alive
        log.log(logging.INFO if alive else logging.WARNING, "zenoh: robot %s", "present" if alive else "gone")

    def _on_joint_states(self, sample: Any) -> None:
        r = rc.parse_joint_state(sample.payload.to_bytes())
        if isinstance(r, rc.Rejected):
            self.rejects.reject(r.key, r.reason)
            return
        stamp, names, q, dq = r
        unknown = [n for n in names if n not in self._q]
        if unknown:
            self.rejects.reject(
                "unknown_joint", f"JointState names unknown joint(s) {unknown}; valid: {list(self.joint_names)}"
            )
            return
        with self._lock:
            for n, a, b in zip(names, q, dq, strict=True):
                self._q[n], self._dq[n] = float(a), float(b)
            self._js_stamp = stamp
            self._js_wall = time.monotonic()
            self.received += 1

    def _on_odom(self, sample: Any) -> None:
        r = rc.parse_odometry(sample.payload.to_bytes())
        if isinstance(r, rc.Rejected):
            self.rejects.reject(r.key, r.reason)
            return
        with self._lock:
            self._odom = (r[1], r[2])
            self._odom_wall = time.monotonic()

    def _on_runstop(self, sample: Any) -> None:
        m = rc.decode(sample.payload.to_bytes(), "std_msgs/msg/Bool")
        if isinstance(m, rc.Rejected):
            self.rejects.reject(m.key, m.reason)
            return
        with self._lock:
            self._runstop = bool(m.data)
            if self._runstop:
                self._runstop_engaged_wall = time.monotonic()

    def _on_faults(self, sample: Any) -> None:
        m = rc.decode(sample.payload.to_bytes(), "std_msgs/msg/String")
        if isinstance(m, rc.Rejected):
            self.rejects.reject(m.key, m.reason)
            return
        with self._lock:
            self._faults = tuple(f for f in m.data.split("\n") if f)

    def heartbeat_ok(self) -> bool:
        now = time.monotonic()
        with self._lock:
            complete = not any(np.isnan(v) for v in self._q.values())
            return (
                self._robot_alive
                and complete
                and now - self._js_wall <= self.heartbeat_timeout
                and now - self._odom_wall <= self.heartbeat_timeout
            )

    def _latest_state(self) -> RobotState | None:
        with self._lock:
            if self._odom is None or any(np.isnan(v) for v in self._q.values()):
                return None
            q = [self._q[n] for n in self.joint_names]
            return RobotState(
                stamp=self._js_stamp,
                names=self.joint_names,
                q=q,
                dq=[self._dq[n] for n in self.joint_names],
                base=self._odom[0],
                base_velocity=self._odom[1],
                gripper=self._q[self.limits.gripper_joint],
                estopped=self._runstop,
                faults=self._faults,
            )

    # ------------------------------------------------------------------ outgoing
    def _put(self, topic: str, payload: bytes) -> None:
        pub = self._pubs.get(topic)
        if pub is None:
            raise HalError(f"zenoh: not configured (no publisher for {topic!r})")
        pub.put(payload)

    def _send_setpoint(self, sp: JointSetpoint) -> None:
        self._moving["arm"] = bool(np.any(np.abs(sp.dq) > REST_JOINT))
        index = {n: i for i, n in enumerate(sp.names)}
        for t in self.keys.joint_topics():
            mine = [n for n in t.joints if n in index]
            if mine:
                idx = [index[n] for n in mine]
                sub = JointSetpoint(tuple(mine), sp.q[idx], sp.dq[idx])
                self._put(t.name, rc.encode_trajectory(sub, self.control_period))

    def _send_base_velocity(self, vx: float, vy: float, wz: float) -> None:
        self._moving["base"] = max(abs(vx), abs(vy), abs(wz)) > REST_BASE
        self._put("cmd_vel", rc.encode_twist(vx, vy, wz))

    def _send_gripper(self, cmd: GripperCommand) -> None:
        if cmd.action is GripperAction.GRASP:
            self._put("grasp", rc.encode_float64(cmd.force))
            return
        m = self.model.manipulator()
        target = m.open if cmd.action is GripperAction.OPEN else m.closed
        sp = JointSetpoint((self.limits.gripper_joint,), [target])
        self._put("gripper", rc.encode_trajectory(sp, 1.0))

    def _send_estop(self, engaged: bool) -> None:
        """Engaged: commanded from now on, re-sent until the run-stop confirms it (a failed first send too).
        Released: under the same lock as the re-sends, so none follows it."""
        with self._estop_lock:
            self._moving = dict.fromkeys(self._moving, False)  # e-stopped the robot holds; released nothing moves yet
            if not engaged:
                self._put("estop", rc.encode_bool(False))
                self._estop_engaged, self._estop_resending, self._estop_episode_resends = False, False, 0
                return
            self._estop_engaged, self._estop_since = True, time.monotonic()
            try:
                self._put("estop", rc.encode_bool(True))
            except Exception as e:  # latched all the same: the keepalive re-sends it until the robot confirms
                log.error("zenoh: e-stop not sent (%s): re-sending until the robot reports it engaged", e)
