"""``rlgp-exec daemon``: the on-robot execution daemon.

One executive, one robot, one task at a time; further goals wait in a queue. Requests arrive as Zenoh
queries under the daemon's key space (``<namespace>/rlgp/executive/...``), each answered with JSON:

=========================  ==================================================  ===========================
key                        payload                                             reply
=========================  ==================================================  ===========================
``.../goal``               ``{"literals": ["(on block tray)", ...]}``          ``{"ok", "task", "queued"}``
``.../cancel``             (none)                                              ``{"ok", "cancelled"}``
``.../estop``              (none)                                              ``{"ok"}``
``.../rearm``              ``{"confirm": true}``                               ``{"ok"}`` or an error
``.../reset``              ``{"confirm": true}``                               ``{"ok"}`` or an error
``.../status``             (none)                                              the status (below)
=========================  ==================================================  ===========================

A handler acts only on a query for exactly its key: a wildcard (``rlgp/**``, ``**``,
``rlgp/executive/*``) that Zenoh routes to every queryable it intersects gets no reply and runs nothing.
Leaving a safety state is an operator's explicit request: ``rearm`` (ESTOPPED -> IDLE) and ``reset``
(FAULT -> IDLE) need ``{"confirm": true}``, and a goal is refused while the executive is in FAULT or
ESTOPPED (the reply names the request that clears it); goals queued when the executive faults or is
e-stopped are dropped, so none runs on the operator's later reset.

A bad request gets ``{"ok": false, "error": "..."}`` naming what is wrong (at most ``MAX_ERROR`` chars);
the daemon keeps serving. The status — state, current task, queue, last result — is also published on
``.../status`` at every transition and result. On SIGTERM/SIGINT the daemon cancels the running task (a
jerk-limited stop), brings the robot to rest, finishes the recording and exits 0.

The daemon declares nothing outside its key space. Who may ask is the Zenoh configuration's business
(``--zenoh-config``): mutual TLS on the listen endpoint and ``access_control`` rules per client
certificate's common name (see README, "Daemon"). One file serves both of the daemon's sessions (the
robot's, with the zenoh backend, and the clients'), so its rules admit the robot's certificate too.
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import logging
import queue
import threading
import time
from collections import Counter
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rlgp_exec.errors import RlgpError, SceneError
from rlgp_exec.executive.executive import Executive, TaskResult, TaskStatus
from rlgp_exec.executive.recorder import Recorder
from rlgp_exec.executive.runner import RunOptions, connect, object_source_name, record_camera
from rlgp_exec.executive.states import ExecState, Transition
from rlgp_exec.hal.zenoh_keys import exact, open_session, session_config
from rlgp_exec.scene import Scene
from rlgp_exec.scene.literals import parse_goal

__all__ = ["KEYS", "Daemon", "DaemonOptions", "request"]

log = logging.getLogger(__name__)

KEYS = ("goal", "cancel", "estop", "rearm", "reset", "status")
DEFAULT_LISTEN = "tcp/127.0.0.1:7450"
MAX_QUEUE = 8
MAX_PAYLOAD = 64 * 1024  # [bytes] a request larger than this is refused unread
MAX_LITERALS = 64  # per goal, and MAX_LITERAL chars each: the status that echoes a goal stays small
MAX_LITERAL = 256
MAX_ERROR = 400  # [chars] of an error message: a reply never echoes a large payload back
CONFIRM = {"confirm": True}
# what a goal is refused in, and the request that clears it
_BLOCKED = {ExecState.FAULT: "reset", ExecState.ESTOPPED: "rearm"}


@dataclass(frozen=True)
class DaemonOptions:
    listen: str | None = DEFAULT_LISTEN  # where clients connect; None: the zenoh_config's endpoints
    namespace: str = ""  # key prefix of the daemon's key space
    record_dir: Path | None = None  # one MCAP per task
    zenoh_config: Path | None = None  # json5 for the client-facing session (TLS, access control)


@dataclass(frozen=True)
class _Task:
    id: int
    literals: tuple[str, ...]


class Daemon:
    def __init__(self, scene: Scene, run: RunOptions, opts: DaemonOptions) -> None:
        self.scene, self.run_opts, self.opts = scene, run, opts
        prefix = f"{opts.namespace.strip('/')}/" if opts.namespace.strip("/") else ""
        self.base = f"{prefix}rlgp/executive"
        self.queue: queue.Queue[_Task | None] = queue.Queue(MAX_QUEUE)
        self.current: _Task | None = None
        self.last: dict[str, Any] | None = None
        self.served = 0
        self.progress: dict[str, int] | None = None
        self.ignored: Counter[str] = Counter()  # queries not for exactly a key of ours, per key reached
        self.dropped = 0  # queued goals dropped on a fault or e-stop
        self._next_id = 1
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._session: Any = None
        self._pub: Any = None
        self._decls: list[Any] = []
        self.executive: Executive | None = None
        self._hal: Any = None
        self._objects: Any = None
        self._worker: threading.Thread | None = None
        self.waiting: str | None = None  # what the next task waits for: "robot", "rearm", "reset"
        self.recording_error: str | None = None
        self.fatal: str | None = None  # why the worker died (then no goal runs any more)
        self.dead = threading.Event()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        """Connect to the robot, open the client-facing session, serve. Any failure (no robot, a bad or
        busy endpoint, an unreadable configuration) closes what was opened and raises RlgpError."""
        try:
            self._start()
        except RlgpError:
            self._close()
            raise
        except Exception as e:  # an unforeseen Zenoh error is still a start-up error: one line, exit 2
            log.debug("daemon: start-up failed", exc_info=True)
            self._close()
            raise RlgpError(f"daemon: start-up failed: {type(e).__name__}: {e}") from e
        except BaseException:  # KeyboardInterrupt while connecting
            self._close()
            raise

    def _start(self) -> None:
        # the client-facing configuration is checked before the robot is connected: a typo costs nothing
        config = session_config(listen=self.opts.listen, config_file=self.opts.zenoh_config)
        self._hal, self._objects = connect(self.scene, self.run_opts)
        self.executive = Executive(
            self._hal, self.scene, self._objects, planner=self.run_opts.planner, seed=self.run_opts.seed,
            limits=self.run_opts.limits,
        )
        self.executive.sm.listeners.append(self._on_transition)
        self.executive.on_recording_error = self._on_recording_error
        self.executive.actor.on_phase = self._on_phase
        self._session = open_session(config, f"daemon: cannot listen on {self.opts.listen or self.opts.zenoh_config}")
        self._pub = self._session.declare_publisher(f"{self.base}/status")
        handlers = {
            "goal": self._on_goal,
            "cancel": self._on_cancel,
            "estop": self._on_estop,
            "rearm": self._on_rearm,
            "reset": self._on_reset,
            "status": lambda _: self.status(),
        }
        for name, fn in handlers.items():
            key = f"{self.base}/{name}"
            self._decls.append(self._session.declare_queryable(key, self._guard(key, fn)))
        self._worker = threading.Thread(target=self._work, name="executive", daemon=True)
        self._worker.start()
        where = self.opts.listen or self.opts.zenoh_config
        log.info("daemon: serving %s/{%s} on %s", self.base, ",".join(KEYS), where)

    def stop(self) -> None:
        """Graceful: cancel the running task (jerk-limited stop), wait for rest, close everything."""
        self._stop.set()
        if self.executive is not None:
            self.executive.cancel()
        with contextlib.suppress(queue.Full):
            self.queue.put_nowait(None)
        if self._worker is not None:
            self._worker.join(timeout=15.0)
        self._close()
        log.info("daemon: stopped after %d task(s)", self.served)

    def _close(self) -> None:
        for d in self._decls:
            try:
                d.undeclare()
            except Exception as e:  # closing anyway
                log.debug("undeclare: %s", e)
        self._decls.clear()
        if self._session is not None:
            self._session.close()
            self._session = None
        if self._objects is not None:
            self._objects.close()
            self._objects = None
        if self._hal is not None:
            self._hal.shutdown()
            self._hal = None

    # ------------------------------------------------------------------ requests
    def _guard(self, key: str, fn):
        def handler(query: Any) -> None:
            if not exact(query, key):  # a wildcard reached us: not a request for this key
                self.ignored[key] += 1
                log.debug("daemon: ignored query %s (not exactly %s)", query.key_expr, key)
                return
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                reply = fn(payload) if len(payload) <= MAX_PAYLOAD else _err(f"payload over {MAX_PAYLOAD} bytes")
            except Exception as e:  # a request never takes the daemon down
                log.exception("daemon: request failed")
                reply = _err(f"internal error: {type(e).__name__}: {e}")
            try:
                query.reply(key, json.dumps(reply).encode())
            except Exception as e:  # the client went away, or the session is closing
                log.debug("daemon: reply to %s: %s", key, e)

        return handler

    def _on_goal(self, payload: bytes) -> dict[str, Any]:
        if self._stop.is_set():
            return _err("shutting down")
        if self.fatal is not None:
            return _err(f"not accepting goals: {self.fatal}; restart the daemon")
        try:
            req = json.loads(payload or b"null")
        except ValueError as e:
            return _err(f"goal: not JSON: {e}")
        if not isinstance(req, dict) or set(req) - {"literals"} or "literals" not in req:
            return _err('goal: expected {"literals": ["(on block tray)", ...]}')
        lits = req["literals"]
        if not isinstance(lits, list) or not lits or not all(isinstance(x, str) for x in lits):
            return _err("goal: literals must be a non-empty list of strings")
        if len(lits) > MAX_LITERALS or max(map(len, lits)) > MAX_LITERAL:
            return _err(f"goal: at most {MAX_LITERALS} literals of at most {MAX_LITERAL} characters")

        def fail(where: str, msg: str) -> SceneError:
            return SceneError("goal", where, msg)

        try:
            parse_goal(lits, self.scene, fail)
        except SceneError as e:
            return _err(str(e))
        with self._lock:  # against _on_transition: a goal is queued before a fault drops it, or refused
            assert self.executive is not None
            blocked = _BLOCKED.get(self.executive.sm.state)
            if blocked is not None:
                return _err(
                    f"goal refused: the executive is {self.executive.sm.state.name}; "
                    f'an operator must send {blocked} {{"confirm": true}} first'
                )
            task = _Task(self._next_id, tuple(lits))
            try:
                self.queue.put_nowait(task)
            except queue.Full:
                return _err(f"queue full ({MAX_QUEUE} tasks waiting)")
            self._next_id += 1
        return {"ok": True, "task": task.id, "queued": self.queue.qsize()}

    def _drain(self) -> int:
        """Drop the queued goals (not the stop marker); how many."""
        dropped = 0
        while True:
            try:
                t = self.queue.get_nowait()
            except queue.Empty:
                break
            if t is None:
                self.queue.put_nowait(None)
                break
            dropped += 1
        return dropped

    def _on_cancel(self, _: bytes) -> dict[str, Any]:
        dropped = self._drain()
        assert self.executive is not None
        self.executive.cancel()
        return {"ok": True, "cancelled": self.current.id if self.current else None, "dropped": dropped}

    def _on_estop(self, _: bytes) -> dict[str, Any]:
        assert self.executive is not None
        self.executive.estop()
        return {"ok": True}

    def _on_rearm(self, payload: bytes) -> dict[str, Any]:
        assert self.executive is not None
        refused = _confirmed("rearm", payload)
        if refused:
            return refused
        try:
            self.executive.rearm()
        except RlgpError as e:
            return _err(str(e))
        return {"ok": True}

    def _on_reset(self, payload: bytes) -> dict[str, Any]:
        assert self.executive is not None
        refused = _confirmed("reset", payload)
        if refused:
            return refused
        if self.executive.sm.state is not ExecState.FAULT:
            return _err(f"reset: the executive is {self.executive.sm.state.name}, not FAULT")
        try:
            self.executive.reset()
        except RlgpError as e:  # the executive may refuse (the robot not healthy yet): say why
            return _err(f"reset: {e}")
        return {"ok": True}

    def status(self) -> dict[str, Any]:
        ex = self.executive
        return {
            "ok": True,
            "state": ex.sm.state.value if ex else "starting",
            "reason": ex.sm.reason if ex else "",
            "waiting": self.waiting,
            "fatal": self.fatal,
            "recording_error": self.recording_error,
            "task": None if self.current is None else {"id": self.current.id, "goal": list(self.current.literals)},
            "queued": self.queue.qsize(),
            "served": self.served,
            "dropped": self.dropped,
            "progress": self.progress if self.current is not None else None,
            "last": self.last,
            "estop": None if ex is None else dataclasses.asdict(ex.hal.estop_status()),
        }

    def _publish(self) -> None:
        try:
            self._pub.put(json.dumps(self.status()).encode())
        except Exception as e:  # the session is closing
            log.debug("status publish: %s", e)

    def _on_transition(self, tr: Transition) -> None:
        if tr.target in _BLOCKED:
            with self._lock:
                dropped = self._drain()
                self.dropped += dropped
            if dropped:
                log.warning("daemon: %s: dropped %d queued goal(s)", tr.target.name, dropped)
        self._publish()

    def _on_recording_error(self, why: str) -> None:
        self.recording_error = f"task {self.current.id if self.current else '?'}: {why}"
        self._publish()

    def _on_phase(self, k: int, n: int) -> None:
        self.progress = {"phase": k + 1, "phases": n}
        self._publish()

    # ------------------------------------------------------------------ the worker
    def _work(self) -> None:
        """One task at a time. Supervised: should anything escape a task, the robot is brought to rest,
        FAULT is latched and published, and the daemon stops serving goals (``fatal``; the CLI exits 1)."""
        assert self.executive is not None
        try:
            while not self._stop.is_set():
                task = self.queue.get()
                if task is None or self._stop.is_set():
                    break
                self.current = task
                self.executive.signals.cancel.clear()  # a cancel before this task began is not for it
                ready = self._wait_until_ready()
                result = self._run(task) if ready is None else ready
                self.last = {"task": task.id, **result.as_dict()}
                self.current = None
                self.served += 1
                self._publish()
        except BaseException as e:
            self._die(e)

    def _die(self, e: BaseException) -> None:
        why = f"the executive's worker died: {type(e).__name__}: {e}"
        log.critical("daemon: %s", why, exc_info=e)
        self.fatal = why
        assert self.executive is not None
        try:
            self.executive._fault(why)
        except BaseException:
            log.exception("daemon: could not latch FAULT")
        self.dead.set()
        self._publish()

    def _wait_until_ready(self) -> TaskResult | None:
        """Before a task runs: wait for fresh robot state and for the executive to leave a latched state
        (an operator's rearm or reset), saying so on status; None when ready, else the task's result
        (cancelled, or the daemon stopping)."""
        ex = self.executive
        assert ex is not None and self.current is not None
        published = None
        while True:
            state = ex.sm.state
            waiting = (
                "rearm" if state is ExecState.ESTOPPED else "reset" if state is ExecState.FAULT
                else None if ex.robot_ready() else "robot"
            )
            if waiting is None:
                if published is not None:
                    log.info("daemon: task %d starts (was waiting for %s)", self.current.id, published)
                self.waiting = None
                return None
            if self._stop.is_set() or ex.signals.cancel.is_set():
                self.waiting = None
                what = "the daemon stopped" if self._stop.is_set() else "cancelled"
                return TaskResult(TaskStatus.CANCELLED, f"{what} while waiting for {waiting}", self.current.literals)
            if waiting != published:
                log.warning("daemon: task %d waits for %s", self.current.id, _WAITING[waiting])
                self.waiting, published = waiting, waiting
                self._publish()
            time.sleep(0.05)

    def _run(self, task: _Task) -> TaskResult:
        assert self.executive is not None
        ex = self.executive
        recorder = None
        if self.opts.record_dir is not None:
            stamp = time.strftime("%Y%m%d-%H%M%S")
            try:
                recorder = Recorder(self.opts.record_dir / f"task{task.id:04d}-{stamp}.mcap")
            except (OSError, RlgpError) as e:  # the task runs; the status says it is not recorded
                log.error("daemon: task %d not recorded: %s", task.id, e)
                self.recording_error = f"task {task.id}: {e}"
        with contextlib.ExitStack() as stack:
            if recorder is not None:
                stack.callback(recorder.close)
            hz = self.run_opts.camera_record_hz
            if recorder is not None and hz > 0 and object_source_name(self.run_opts) == "camera":
                try:  # the robot's camera topics, or a local camera's frames as it reads them
                    record_camera(stack, recorder, self._hal, self._objects, self.run_opts)
                except Exception as e:  # a session that refuses the subscription: recorded without images
                    log.error("daemon: task %d recorded without the camera's images: %s", task.id, e)
            ex.attach(recorder)
            stack.callback(ex.attach, None)
            return ex.run(list(task.literals))
        raise AssertionError("unreachable")


_WAITING = {"robot": "fresh robot state", "rearm": "an operator's rearm", "reset": "an operator's reset"}


def _err(msg: str) -> dict[str, Any]:
    return {"ok": False, "error": msg if len(msg) <= MAX_ERROR else msg[: MAX_ERROR - 3] + "..."}


def _confirmed(what: str, payload: bytes) -> dict[str, Any] | None:
    """None when ``payload`` is exactly {"confirm": true}; else the refusal."""
    try:
        req = json.loads(payload) if payload else None
    except ValueError:
        req = None
    if req != CONFIRM or not isinstance(req.get("confirm"), bool):  # 1 == True: not a confirmation
        return _err(f'{what}: changes the robot\'s safety state: send {{"confirm": true}} to confirm')
    return None


def request(
    endpoint: str | None,
    what: str,
    payload: dict[str, Any] | None = None,
    namespace: str = "",
    timeout_s: float = 5.0,
    zenoh_config: str | Path | None = None,
) -> dict[str, Any]:
    """A client call: one query to a daemon at ``endpoint`` (None: the ``zenoh_config``'s connect endpoints);
    the JSON reply (or an error dict). ``rearm`` and ``reset`` are sent confirmed: calling them is the
    operator's explicit request."""
    if what not in KEYS:
        raise RlgpError(f"unknown daemon request {what!r}; valid: {list(KEYS)}")
    if what in ("rearm", "reset") and payload is None:
        payload = CONFIRM
    prefix = f"{namespace.strip('/')}/" if namespace.strip("/") else ""
    where = endpoint or zenoh_config
    s = open_session(session_config(connect=endpoint, config_file=zenoh_config), f"request: cannot open {where}")
    try:
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            body = json.dumps(payload).encode() if payload is not None else None
            for r in s.get(f"{prefix}rlgp/executive/{what}", payload=body, timeout=max(0.1, end - time.monotonic())):
                if r.ok is not None:
                    return json.loads(r.ok.payload.to_bytes())
            time.sleep(0.1)  # not connected yet
        return _err(f"no daemon answered at {where} within {timeout_s} s")
    finally:
        s.close()
