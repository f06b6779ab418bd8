"""The daemon's and the robot server's request surface over real Zenoh sessions on loopback: wildcard
queries and puts command nothing, safety states are left only on a confirmed request, a bounded fuzz of
requests leaves the daemon serving, start-up errors exit 2 with one line and nothing left running, and
the robot server holds within its 0.5 s deadline when the executive falls silent mid-motion."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from waiting import wait_for

from rlgp_exec.executive.daemon import MAX_ERROR, MAX_PAYLOAD, Daemon, DaemonOptions, request
from rlgp_exec.executive.runner import RunOptions
from rlgp_exec.executive.states import ExecState
from rlgp_exec.hal import JointSetpoint
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.sim_physics import SimRobot
from rlgp_exec.hal.zenoh_keys import session_config
from rlgp_exec.scene import load_scene
from rlgp_exec.sim.robot_process import free_endpoint
from rlgp_exec.sim.robot_server import COMMAND_DEADLINE_S, LOST, SILENT, ZenohRobotServer

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "shelf_hsr.toml"
NS = "lab"
WILDCARDS = ["**", "lab/**", "lab/rlgp/**", "lab/rlgp/executive/*", "lab/rlgp/executive/**", "lab/*/executive/rearm",
             "*/rlgp/executive/estop", "lab/rlgp/*/reset", "lab/rlgp/executive/re$*"]  # fmt: skip
MAX_REPLY = 2048  # [bytes] every reply the fuzz gets stays under this


# ---------------------------------------------------------------------------------- the daemon
@pytest.fixture(scope="module")
def served() -> Iterator[tuple[Daemon, object, str]]:
    """A daemon (in-process sim robot) and a raw client session on its endpoint."""
    import zenoh

    ep = free_endpoint()
    daemon = Daemon(load_scene(SCENE), RunOptions(backend="sim"), DaemonOptions(ep, NS))
    daemon.start()
    client = zenoh.open(session_config(connect=ep))
    assert wait_for(lambda: _ask(client, "status") is not None, 5.0, 0.05)
    yield daemon, client, ep
    client.close()
    daemon.stop()


def _replies(client, key: str, payload: bytes | None = None, timeout: float = 1.0) -> list[bytes]:
    return [r.ok.payload.to_bytes() for r in client.get(key, payload=payload, timeout=timeout) if r.ok is not None]


def _ask(client, what: str, payload: object = None) -> dict | None:
    body = None if payload is None else json.dumps(payload).encode()
    got = _replies(client, f"{NS}/rlgp/executive/{what}", body)
    return json.loads(got[0]) if got else None


def _idle(daemon: Daemon) -> None:
    """Back to IDLE, whichever test (or xdist order) left the shared daemon e-stopped."""
    ex = daemon.executive
    if ex.sm.state is ExecState.FAULT:
        ex.reset()
    if ex.sm.state is ExecState.ESTOPPED:
        ex.rearm()
    assert ex.sm.state is ExecState.IDLE


def test_wildcard_queries_run_no_handler(served):
    daemon, client, _ = served
    ex = daemon.executive
    _idle(daemon)
    for confirmed in (None, b'{"confirm": true}', b'{"literals": ["(on block tray)"]}'):
        for key in WILDCARDS:
            before = sum(daemon.ignored.values())
            assert _replies(client, key, confirmed) == [], key
            assert sum(daemon.ignored.values()) > before, f"{key} reached no queryable: the test proves nothing"
            assert ex.sm.state is ExecState.IDLE and not ex.signals.estop.is_set() and not ex.signals.cancel.is_set()
    assert daemon.queue.empty() and daemon.served == 0
    # e-stopped, a wildcard carrying the confirmation does not re-arm (or reset) it
    assert _ask(client, "estop") == {"ok": True} and ex.sm.state is ExecState.ESTOPPED
    for key in WILDCARDS:
        assert _replies(client, key, b'{"confirm": true}') == []
    assert ex.sm.state is ExecState.ESTOPPED
    assert _ask(client, "rearm", {"confirm": True}) == {"ok": True} and ex.sm.state is ExecState.IDLE


def test_safety_states_are_left_only_on_a_confirmed_request(served):
    daemon, client, ep = served
    ex = daemon.executive
    _idle(daemon)
    assert _ask(client, "estop")["ok"] and ex.sm.state is ExecState.ESTOPPED
    for bad in (None, {}, {"confirm": False}, {"confirm": 1}, {"confirm": "yes"}, {"confirm": True, "x": 1}, [True]):
        r = _ask(client, "rearm", bad)
        assert r["ok"] is False and '{"confirm": true}' in r["error"], (bad, r)
    r = _ask(client, "goal", {"literals": ["(on block tray)"]})
    assert r["ok"] is False and "ESTOPPED" in r["error"] and "rearm" in r["error"], r
    assert _ask(client, "reset", {"confirm": True})["error"].startswith("reset: the executive is ESTOPPED")
    assert ex.sm.state is ExecState.ESTOPPED and daemon.queue.empty()
    assert request(ep, "rearm", namespace=NS)["ok"]  # the client call confirms: calling it is the request
    assert ex.sm.state is ExecState.IDLE

    ex._fault("injected by the test")  # what a lost robot or a tracking error ends in
    assert ex.sm.state is ExecState.FAULT
    r = _ask(client, "goal", {"literals": ["(on block tray)"]})
    assert r["ok"] is False and "FAULT" in r["error"] and "reset" in r["error"], r
    assert _ask(client, "reset", {"confirm": 1})["ok"] is False and ex.sm.state is ExecState.FAULT
    assert _ask(client, "reset", {"confirm": True}) == {"ok": True} and ex.sm.state is ExecState.IDLE
    assert _ask(client, "reset", {"confirm": True})["ok"] is False  # not in FAULT: a clear refusal
    assert daemon.queue.empty() and daemon.served == 0


_json = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=30),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=10), inner, max_size=4),
    max_leaves=12,
)
_payload = st.one_of(
    _json.map(lambda v: json.dumps(v).encode()),
    st.binary(max_size=200),
    st.dictionaries(st.sampled_from(["literals", "confirm", "goal"]), _json, max_size=2).map(
        lambda v: json.dumps(v).encode()
    ),
    st.lists(st.text(max_size=300), min_size=1, max_size=80).map(lambda v: json.dumps({"literals": v}).encode()),
    st.sampled_from([b"x" * (MAX_PAYLOAD + 1), json.dumps({"literals": ["(on block tray)" * 5000]}).encode()]),
    st.sampled_from([b'{"confirm": true}', b'{"confirm": 1}', b'{"confirm": "true"}', b'{"confirm": true, "a": 0}']),
)
_case = st.one_of(
    st.tuples(st.sampled_from(["goal", "rearm", "reset", "status", "cancel", "estop"]), _payload),
    st.tuples(st.sampled_from(WILDCARDS), _payload),
)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=_case)
def test_fuzzed_requests_leave_the_daemon_serving_and_command_nothing(served, case):
    """E-stopped throughout: no payload but exactly {"confirm": true} on exactly .../rearm leaves it (that one
    is left out), no goal is queued, wildcards reach no handler, every reply is small and names its error."""
    daemon, client, _ = served
    ex = daemon.executive
    if ex.sm.state is not ExecState.ESTOPPED:
        ex.estop()
    key, payload = case
    if key == "rearm" and payload == b'{"confirm": true}':
        payload = b'{"confirm": true, "by": "fuzz"}'
    full = key if "*" in key or "$" in key else f"{NS}/rlgp/executive/{key}"
    got = _replies(client, full, payload)
    if full != f"{NS}/rlgp/executive/{key}":
        assert got == [], (full, got)
    else:
        assert len(got) == 1 and len(got[0]) <= MAX_REPLY, (full, payload[:60], got)
        r = json.loads(got[0])
        assert isinstance(r, dict) and isinstance(r["ok"], bool)
        if not r["ok"]:
            assert 0 < len(r["error"]) <= MAX_ERROR
        assert key in ("status", "cancel", "estop") or not r["ok"], (key, payload[:60], r)
    assert ex.sm.state is ExecState.ESTOPPED and daemon.queue.empty() and daemon.served == 0
    assert _ask(client, "status")["state"] == "estopped"  # still serving
    # the status says the e-stop is commanded and that the robot's own state confirms it
    assert wait_for(lambda: _ask(client, "status")["estop"] == {"engaged": True, "confirmed": True,
                                                             "resends": ex.hal.estop_status().resends}, 5.0, 0.05)


# ---------------------------------------------------------------------------------- the robot server
@pytest.fixture
def robot() -> Iterator[tuple[ZenohRobotServer, object]]:
    import zenoh

    ep = free_endpoint()
    sim = SimRobot("hsr")
    server = ZenohRobotServer(sim, ep)
    server.start()
    client = zenoh.open(session_config(connect=ep))
    assert wait_for(lambda: server.stats()["ticks"] > 5, 5.0)
    time.sleep(0.3)  # the client's declarations reach the server
    yield server, client
    client.close()
    server.stop()
    sim.close()


def test_wildcard_puts_move_nothing_and_release_no_estop(robot):
    server, client = robot
    k = server.keys
    with server.lock:
        server.sim.estop(True)
    base0, q0 = server.sim.state().base, np.asarray(server.sim.state().q).copy()
    arm = k["arm"]
    for key in ("**", "hsrb/**", "hsrb/*", "rlgp/*", "rlgp/**", "hsrb/arm_trajectory_controller/*"):
        client.put(key, rc.encode_bool(False))
        client.put(key, rc.encode_twist(0.2, 0.0, 0.0))
        client.put(key, rc.encode_trajectory(JointSetpoint(arm.joints, [0.3] * len(arm.joints)), 0.01))
    assert wait_for(lambda: server.rejects.counts().get("wildcard", 0) >= 6 * 3, 2.0), server.rejects.counts()
    assert server.sim.estopped and not server.accepted
    with server.lock:
        server.sim.estop(False)
    for key in ("**", "hsrb/**"):
        client.put(key, rc.encode_twist(0.2, 0.0, 0.0))
    time.sleep(0.3)
    st_ = server.sim.state()
    assert np.allclose(st_.base, base0, atol=1e-3) and np.allclose(st_.q, q0, atol=2e-3)
    client.liveliness().declare_token("rlgp/alive/**")  # a wildcard token: not the executive's
    assert wait_for(lambda: server.rejects.counts().get("wildcard", 0) > 6 * 3 + 2, 2.0), server.rejects.counts()


def test_the_zenoh_hal_takes_state_only_from_its_exact_keys(robot):
    from rlgp_exec.hal import make_backend

    server, _ = robot
    hal = make_backend("zenoh", endpoint=server.endpoint)
    hal.configure()
    try:
        assert hal.wait_for_robot(10.0)
        time.sleep(0.2)
        spoof = rc.encode_joint_state(0.0, ["arm_lift_joint"], [0.33], [0.0])
        for key in ("hsrb/*", "hsrb/**", "**"):  # from the robot's side: the one peer the HAL connects to
            server._session.put(key, spoof)
            server._session.put(key, rc.encode_bool(True))  # a run-stop on no key of the robot's
        assert wait_for(lambda: hal.rejects.counts().get("wildcard", 0) >= 6, 2.0), hal.rejects.counts()
        st_ = hal.read_state()
        assert not st_.estopped and st_.position("arm_lift_joint") != pytest.approx(0.33, abs=1e-3)
    finally:
        hal.shutdown()


def test_a_silent_executive_is_held_within_the_deadline(robot):
    """A sender streams a base twist and an arm move, then stops: within 0.5 s + a cycle the base is
    stopped, the arm held where it is (short of the target it was streaming towards) and the fault
    reported; a keepalive clears it. A liveliness token alone clears no fault."""
    server, client = robot
    k = server.keys
    arm = k["arm"]
    i = arm.joints.index("arm_lift_joint")
    q = np.asarray(server.sim.state().positions(arm.joints), dtype=float)
    for _ in range(60):  # 0.6 s at 100 Hz: the base at 0.15 m/s, the lift towards 0.6 m at 0.1 m/s
        target = q.copy()
        target[i] = 0.6
        dq = np.zeros(len(q))
        dq[i] = 0.1
        client.put(k["cmd_vel"].key, rc.encode_twist(0.15, 0.0, 0.0))
        client.put(arm.key, rc.encode_trajectory(JointSetpoint(arm.joints, target, dq), 0.01))
        time.sleep(0.01)
    last = time.monotonic()
    assert wait_for(lambda: abs(server.sim.state().base_velocity[0]) > 0.1, 1.0), "the base never moved"
    assert wait_for(lambda: SILENT in server.sim.faults, COMMAND_DEADLINE_S + 0.5, 0.001)
    held_after = time.monotonic() - last
    assert held_after <= COMMAND_DEADLINE_S + 0.05, f"held {held_after:.3f} s after the last command"
    assert wait_for(lambda: abs(server.sim.state().base_velocity[0]) < 1e-3, 2 * server.period)
    lift = server.sim.state().position("arm_lift_joint")
    time.sleep(0.5)
    assert server.sim.state().position("arm_lift_joint") == pytest.approx(lift, abs=5e-3)  # held, not at 0.6
    assert lift < 0.55 and server.stats()["holds"] == {"silent": 1}
    token = client.liveliness().declare_token(k.alive_executive)
    time.sleep(0.3)
    assert SILENT in server.sim.faults  # presence is not a command
    client.put(k.heartbeat, rc.encode_float64(1.0))
    assert wait_for(lambda: SILENT not in server.sim.faults, 1.0)
    token.undeclare()
    assert wait_for(lambda: LOST in server.sim.faults, 2.0)  # the token gone: lost, held
    client.liveliness().declare_token(k.alive_executive)
    time.sleep(0.3)
    assert LOST in server.sim.faults  # a (possibly spoofed) token does not clear it


def test_an_estop_mid_motion_and_its_rearm_leave_no_silence_fault(robot):
    """E-stopped mid-motion the HAL sends nothing but keepalives; neither then nor after the rearm does
    the robot report the executive silent (which would fault the next task at its first phase)."""
    from rlgp_exec.hal import make_backend

    server, _ = robot
    hal = make_backend("zenoh", endpoint=server.endpoint)
    hal.configure()
    try:
        assert hal.wait_for_robot(10.0)
        hal.activate()
        for _ in range(30):
            assert hal.write_base_velocity(0.15, 0.0, 0.0)
            time.sleep(0.01)
        hal.estop()
        assert wait_for(lambda: server.sim.estopped, 1.0)
        time.sleep(3 * COMMAND_DEADLINE_S)
        assert SILENT not in server.sim.faults
        hal.rearm()
        assert wait_for(lambda: not server.sim.estopped, 1.0)
        time.sleep(3 * COMMAND_DEADLINE_S)
        assert SILENT not in server.sim.faults and server.stats()["holds"] == {}, server.stats()
    finally:
        hal.shutdown()


def test_after_a_stream_stopped_without_its_hold_activate_starts_clean(robot):
    """A stale-state fault mid-motion: the robot's state stops (its loop paused), the HAL's hold cannot
    send the arm's setpoint, so its last command stays a moving one and the robot, once back, holds and
    reports the executive silent. The next activate (after the operator's reset) sends a keepalive and
    returns with that fault cleared, so the next task does not fault on it at its first phase."""
    from rlgp_exec.hal import make_backend
    from rlgp_exec.sim.realtime import RealTimeLoop

    server, _ = robot
    hal = make_backend("zenoh", endpoint=server.endpoint, heartbeat_timeout=0.2)
    hal.configure()
    try:
        assert hal.wait_for_robot(10.0)
        hal.activate()
        lift = hal.read_state().position("arm_lift_joint")
        for k in range(30):
            assert hal.write_setpoint([lift + 0.001 * k], [0.1], names=["arm_lift_joint"])
            time.sleep(0.01)
        server.loop.stop()  # the robot's state stops: stale
        assert wait_for(lambda: not hal.heartbeat_ok(), 2.0)
        hal.deactivate()  # what the executive's fault does: the base stopped, the arm's hold not sendable
        server.loop = RealTimeLoop(server.period, server.tick, "zenoh-robot")
        server.loop.start()
        assert wait_for(lambda: SILENT in (hal.read_state().faults or ()), 3.0), "the robot did not hold"
        hal.activate()
        assert SILENT not in hal.read_state().faults
    finally:
        hal.shutdown()


def test_the_zenoh_hal_keeps_an_idle_robot_quiet_and_a_frozen_one_is_held():
    """The HAL in its own process: idle, its keepalive keeps the robot server from faulting; frozen
    (SIGSTOP) mid-motion, the server holds within 0.5 s + a cycle."""
    ep = free_endpoint()
    sim = SimRobot("hsr")
    server = ZenohRobotServer(sim, ep)
    server.start()
    code = (
        "import sys, time\n"
        "from rlgp_exec.hal import make_backend\n"
        f"hal = make_backend('zenoh', endpoint={ep!r}, heartbeat_timeout=0.5)\n"
        "hal.configure(); assert hal.wait_for_robot(10.0); hal.activate()\n"
        "assert hal.write_setpoint([0.05], names=['arm_lift_joint']) and hal.write_base_velocity(0, 0, 0)\n"
        "print('idle', flush=True); sys.stdin.readline()\n"
        "while True:\n"
        "    hal.write_base_velocity(0.15, 0.0, 0.0); time.sleep(0.01)\n"
    )
    proc = subprocess.Popen(
        [sys.executable, "-c", code], cwd=ROOT, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None and proc.stdin is not None
        assert proc.stdout.readline().strip() == "idle"
        # commanded once (a position target, no feed-forward; a zero twist), then quiet for 1.5 s
        assert wait_for(lambda: server.accepted["cmd_vel"] >= 1 and server.accepted["arm"] >= 1, 2.0)
        time.sleep(1.5)
        assert SILENT not in sim.faults and server.accepted["heartbeat"] >= 10, server.stats()
        proc.stdin.write("go\n")
        proc.stdin.flush()
        assert wait_for(lambda: abs(sim.state().base_velocity[0]) > 0.1, 2.0), "the base never moved"
        os.kill(proc.pid, signal.SIGSTOP)
        stopped = time.monotonic()
        assert wait_for(lambda: SILENT in sim.faults, 2.0, 0.001), "a frozen executive was not noticed"
        assert time.monotonic() - stopped <= COMMAND_DEADLINE_S + 0.05
        assert wait_for(lambda: abs(sim.state().base_velocity[0]) < 1e-3, 2 * server.period)
    finally:
        os.kill(proc.pid, signal.SIGKILL)
        proc.wait(10)
        server.stop()
        sim.close()


# ---------------------------------------------------------------------------------- start-up errors
def _busy_port() -> tuple[socket.socket, str]:
    s = socket.socket()
    s.bind(("127.0.0.1", 0))
    s.listen()
    return s, f"tcp/127.0.0.1:{s.getsockname()[1]}"


def _cli(*argv: str, timeout: float = 60.0) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    env.pop("ZENOH_CONFIG", None)
    t0 = time.monotonic()
    r = subprocess.run(
        [sys.executable, "-m", "rlgp_exec", *argv], cwd=ROOT, env=env, capture_output=True, text=True, timeout=timeout
    )
    r.seconds = time.monotonic() - t0  # type: ignore[attr-defined]
    return r


def _ours(stderr: str) -> list[str]:
    """stderr without PyBullet's import banner (printed by the library, not by us)."""
    return [ln for ln in stderr.strip().splitlines() if not ln.startswith("pybullet build time")]


@pytest.mark.parametrize(
    "argv, says",
    [
        (["sim-robot", "--robot", "hsr", "--transport", "zenoh", "--endpoint", "tls/127.0.0.1:{free}"],
         "is TLS but transport/link/tls lacks"),
        (["sim-robot", "--robot", "hsr", "--transport", "zenoh", "--endpoint", "{busy}"], "Address already in use"),
        (["sim-robot", "--robot", "hsr", "--transport", "zenoh", "--zenoh-config", "/nonexistent/z.json5"],
         "cannot read"),
        (["request", "status", "--endpoint", "tcp/127.0.0.1"], "host:port"),
        (["request", "rearm", "--endpoint", "quic:/x"], "unsupported protocol 'quic:'"),
        (["daemon", "--scene", str(SCENE), "--listen", "tls/127.0.0.1:{free}"], "is TLS but"),
        (["run", str(SCENE), "--backend", "zenoh", "--endpoint", "tls/127.0.0.1:{free}"], "is TLS but"),
        (["daemon", "--scene", str(SCENE), "--zenoh-config", "{bad_config}"], "zenoh config"),
    ],
)  # fmt: skip
def test_start_up_errors_exit_2_with_one_line(argv, says, tmp_path):
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 'peer', transport: { link: { tls: { no_such_field: 1 } } } }")
    sock, busy = _busy_port()
    try:
        args = [a.format(free=free_endpoint().rsplit(":", 1)[1], busy=busy, bad_config=bad) for a in argv]
        r = _cli(*args)
    finally:
        sock.close()
    lines = _ours(r.stderr)
    assert r.returncode == 2, (r.returncode, r.stderr)
    assert len(lines) == 1 and says in lines[0] and "Traceback" not in r.stderr, r.stderr


def test_a_daemon_that_cannot_listen_closes_its_robot_session_and_exits_2(tmp_path):
    """The robot session is open (the daemon connected, declared its liveliness) when the listen endpoint
    turns out to be taken: the process exits 2 at once, and the robot sees the executive leave."""
    ep = free_endpoint()
    sim = SimRobot("hsr")
    server = ZenohRobotServer(sim, ep)
    server.start()
    sock, busy = _busy_port()
    try:
        r = _cli("daemon", "--scene", str(SCENE), "--backend", "zenoh", "--endpoint", ep, "--listen", busy)
        assert r.returncode == 2, r.stderr
        (line,) = _ours(r.stderr)
        assert line.startswith("rlgp-exec daemon: error: daemon: cannot listen on") and "in use" in line, line
        assert server._executive_seen, "the daemon never reached the robot: the test proves nothing"
        assert wait_for(lambda: LOST in sim.faults, 5.0), "the robot session was left open"  # 2 s missed at load 8
    finally:
        sock.close()
        server.stop()
        sim.close()
