"""Security by configuration, end to end over mutual TLS on loopback: a CA and certificates generated
here (``cryptography``), the simulated robot server in its own process, the daemon (its robot session and
its client-facing session) and clients, each with a Zenoh configuration file (``--zenoh-config``).

The robot admits the executive's certificate only (access control by certificate common name); the
daemon admits the robot, an operator (every request) and a viewer (``status`` only). Peers without a
certificate, with one from another CA, or over plain TCP reach nothing; a valid certificate reaches only
what the rules allow it.
"""

from __future__ import annotations

import datetime
import ipaddress
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import pytest
from waiting import wait_for

from rlgp_exec.executive.daemon import Daemon, DaemonOptions, request
from rlgp_exec.executive.runner import RunOptions
from rlgp_exec.executive.states import ExecState
from rlgp_exec.hal import ros_codec as rc
from rlgp_exec.hal.zenoh_keys import load_key_map, open_session, session_config
from rlgp_exec.scene import load_scene
from rlgp_exec.sim.robot_process import free_endpoint

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "shelf_hsr.toml"
DENIED_S = 0.6  # [s] how long a client waits for an answer that must not come
ALL_MESSAGES = [
    "put", "delete", "declare_subscriber", "query", "reply", "declare_queryable",
    "liveliness_token", "liveliness_query", "declare_liveliness_subscriber",
]  # fmt: skip


# ---------------------------------------------------------------------------------- certificates
def _pki(d: Path) -> None:
    """A CA signing robot, executive, operator and viewer; a rogue CA signing another 'operator'."""
    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

    now = datetime.datetime.now(datetime.UTC)

    def name(cn: str) -> x509.Name:
        return x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, cn)])

    def builder(subject: str, issuer: x509.Name, key) -> x509.CertificateBuilder:
        return (
            x509.CertificateBuilder()
            .subject_name(name(subject))
            .issuer_name(issuer)
            .public_key(key.public_key())
            .serial_number(x509.random_serial_number())
            .not_valid_before(now - datetime.timedelta(minutes=5))
            .not_valid_after(now + datetime.timedelta(hours=2))
        )

    def write(stem: str, cert, key) -> None:
        (d / f"{stem}.pem").write_bytes(cert.public_bytes(serialization.Encoding.PEM))
        (d / f"{stem}.key").write_bytes(
            key.private_bytes(
                serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8, serialization.NoEncryption()
            )
        )

    for ca_name, leaves in (("ca", ("robot", "executive", "operator", "viewer")), ("rogue_ca", ("operator",))):
        ca_key = ec.generate_private_key(ec.SECP256R1())
        ca = (
            builder(ca_name, name(ca_name), ca_key)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), critical=True)
            .add_extension(x509.KeyUsage(True, False, False, False, False, True, True, False, False), critical=True)
            .add_extension(x509.SubjectKeyIdentifier.from_public_key(ca_key.public_key()), critical=False)
            .sign(ca_key, hashes.SHA256())
        )
        write(ca_name, ca, ca_key)
        for cn in leaves:
            key = ec.generate_private_key(ec.SECP256R1())
            cert = (
                builder(cn, ca.subject, key)
                .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
                .add_extension(
                    x509.SubjectAlternativeName(
                        [x509.DNSName("localhost"), x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]
                    ),
                    critical=False,
                )
                .add_extension(
                    x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]),
                    critical=False,
                )
                .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(ca_key.public_key()), critical=False)
                .sign(ca_key, hashes.SHA256())
            )
            write(cn if ca_name == "ca" else f"rogue_{cn}", cert, key)


def _config(d: Path, file: str, cert: str | None, ca: str = "ca", acl: dict | None = None) -> Path:
    tls: dict = {"root_ca_certificate": str(d / f"{ca}.pem"), "enable_mtls": True}
    if cert is not None:
        for role in ("listen", "connect"):
            tls[f"{role}_certificate"] = str(d / f"{cert}.pem")
            tls[f"{role}_private_key"] = str(d / f"{cert}.key")
    cfg: dict = {"mode": "peer", "transport": {"link": {"tls": tls}}}
    if acl is not None:
        cfg["access_control"] = acl
    path = d / file
    path.write_text(json.dumps(cfg, indent=2))
    return path


def _acl(subjects: dict[str, list[str]], rules: dict[str, tuple[list[str], list[str]]]) -> dict:
    """Default deny; ``subjects``: common name -> the rules it is allowed; ``rules``: id -> (messages, keys)."""
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {"id": rid, "permission": "allow", "flows": ["ingress", "egress"], "messages": m, "key_exprs": k}
            for rid, (m, k) in rules.items()
        ],
        "subjects": [{"id": cn, "cert_common_names": [cn]} for cn in subjects],
        "policies": [{"rules": r, "subjects": [cn]} for cn, r in subjects.items()],
    }


@pytest.fixture(scope="module")
def pki(tmp_path_factory) -> dict[str, Path]:
    d = tmp_path_factory.mktemp("pki")
    _pki(d)
    everything = {"all": (ALL_MESSAGES, ["**"])}
    return {
        "robot": _config(d, "robot.json5", "robot", acl=_acl({"executive": ["all"]}, everything)),
        "daemon": _config(
            d,
            "daemon.json5",
            "executive",
            acl=_acl(
                {"robot": ["all"], "operator": ["requests"], "viewer": ["status"]},
                {
                    "all": (ALL_MESSAGES, ["**"]),
                    "requests": (["query", "reply", "declare_queryable"], ["rlgp/executive/*"]),
                    "status": (["query", "reply", "declare_queryable"], ["rlgp/executive/status"]),
                },
            ),
        ),
        "operator": _config(d, "operator.json5", "operator"),
        "viewer": _config(d, "viewer.json5", "viewer"),
        "rogue": _config(d, "rogue.json5", "rogue_operator", ca="rogue_ca"),  # trusts its own CA only
        "rogue_cert": _config(d, "rogue_cert.json5", "rogue_operator"),  # a rogue certificate for our CA
        "no_cert": _config(d, "no_cert.json5", None),
    }


def _tls(ep: str) -> str:
    return ep.replace("tcp/", "tls/", 1)


# ---------------------------------------------------------------------------------- the test
def test_mutual_tls_and_access_control_keep_unauthorised_peers_from_commanding(pki):
    robot_ep, daemon_ep = _tls(free_endpoint()), _tls(free_endpoint())
    robot = subprocess.Popen(
        [sys.executable, "-m", "rlgp_exec.sim.robot_server", "--robot", "hsr", "--transport", "zenoh",
         "--endpoint", robot_ep, "--zenoh-config", str(pki["robot"])],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )  # fmt: skip
    daemon = None
    try:
        line = robot.stdout.readline() if robot.stdout else ""
        if "ready" not in line:
            robot.kill()
            pytest.fail(f"the robot server did not start: {line} {robot.communicate()[1]}")
        daemon = Daemon(
            load_scene(SCENE),
            RunOptions(backend="zenoh", endpoint=robot_ep, zenoh_config=pki["daemon"], connect_timeout_s=15.0),
            DaemonOptions(daemon_ep, zenoh_config=pki["daemon"]),
        )
        daemon.start()  # the daemon's robot session passed the robot's mTLS and its access control
        hal = daemon.executive.hal
        keys = load_key_map("hsr")

        def ask(who: str, what: str, payload=None, timeout_s: float = 5.0) -> dict:
            return request(daemon_ep, what, payload, timeout_s=timeout_s, zenoh_config=pki[who])

        def robot_stats() -> dict:
            replies = list(hal.session.get(keys.stats, timeout=2.0))
            return json.loads(replies[0].ok.payload.to_bytes())

        # the operator e-stops the robot through the daemon
        assert ask("operator", "estop")["ok"]
        assert wait_for(lambda: hal.read_state().estopped, 2.0), "the e-stop did not reach the robot"
        base0 = hal.read_state().base

        # peers the robot does not admit try to move it and to release its e-stop
        attackers = [("rogue", robot_ep), ("rogue_cert", robot_ep), ("no_cert", robot_ep),
                     ("operator", robot_ep),  # a valid certificate, but not the executive's
                     (None, robot_ep.replace("tls/", "tcp/", 1))]  # fmt: skip
        for who, ep in attackers:
            _attack(ep, None if who is None else pki[who], keys)
        time.sleep(0.3)
        st = hal.read_state()
        assert st.estopped, "an unauthorised peer released the e-stop"
        assert max(abs(a - b) for a, b in zip(st.base, base0, strict=True)) < 1e-3, (st.base, base0)
        stats = robot_stats()
        # only the executive's heartbeats and its e-stop were taken (re-sent while the robot did not confirm it)
        sent = 1 + hal.estop_status().resends
        assert stats["accepted"] == {"estop": sent, "heartbeat": stats["accepted"]["heartbeat"]}, (stats, sent)

        # daemon requests: no answer without an admitted certificate; the viewer gets status only
        for who in ("rogue", "rogue_cert", "no_cert", "viewer"):
            for what, payload in (("goal", {"literals": ["(on block tray)"]}), ("rearm", None)):
                r = ask(who, what, payload, timeout_s=DENIED_S)
                assert not r["ok"] and "no daemon answered" in r["error"], (who, what, r)
        plain = request(daemon_ep.replace("tls/", "tcp/", 1), "rearm", timeout_s=DENIED_S)
        assert "no daemon answered" in plain["error"], plain
        assert ask("viewer", "status")["state"] == "estopped"
        assert daemon.executive.sm.state is ExecState.ESTOPPED and daemon.served == 0 and daemon.queue.empty()

        # the operator is answered: a goal is refused while e-stopped (naming rearm), rearm releases
        r = ask("operator", "goal", {"literals": ["(on block tray)"]})
        assert not r["ok"] and "rearm" in r["error"], r
        assert ask("operator", "rearm")["ok"]
        assert wait_for(lambda: not hal.read_state().estopped, 2.0), "the operator's rearm did not reach the robot"

        # released, the robot still moves for nobody but the executive
        base1 = hal.read_state().base
        for who, ep in attackers:
            _attack(ep, None if who is None else pki[who], keys)
        time.sleep(0.3)
        st = hal.read_state()
        assert not st.estopped and max(abs(a - b) for a, b in zip(st.base, base1, strict=True)) < 1e-3
        assert set(robot_stats()["accepted"]) == {"estop", "heartbeat"}
    finally:
        if daemon is not None:
            daemon.stop()
        robot.terminate()
        robot.wait(10)


def _attack(ep: str, config: Path | None, keys) -> None:
    """Connect to ``ep`` (as well as it can), then drive the base, move the arm and release the e-stop."""
    s = open_session(session_config(connect=ep, config_file=config), "attacker")
    try:
        time.sleep(0.3)
        arm = keys["arm"]
        for _ in range(5):
            s.put(keys["cmd_vel"].key, rc.encode_twist(0.3, 0.0, 0.0))
            s.put(keys["estop"].key, rc.encode_bool(False))
            s.put(arm.key, rc.encode_trajectory(_setpoint(arm.joints), 0.01))
            s.liveliness().declare_token(keys.alive_executive)
            time.sleep(0.02)
    finally:
        s.close()


def _setpoint(joints):
    from rlgp_exec.hal import JointSetpoint

    return JointSetpoint(joints, [0.2] * len(joints))


def test_a_daemon_started_from_a_config_file_serves_over_mutual_tls_only(pki, tmp_path):
    """``rlgp-exec daemon --config``: the file names the scene, the TLS listen endpoint and the Zenoh
    configuration (relative to the file); its certificates and access control then apply as above."""
    ep = _tls(free_endpoint())
    (tmp_path / "conf").mkdir()
    (tmp_path / "conf" / "session.json5").write_text(pki["daemon"].read_text())
    cfg = tmp_path / "conf" / "daemon.toml"
    cfg.write_text(f'robot = "hsr"\nbackend = "sim"\nscene = "{SCENE}"\nlisten = "{ep}"\n'
                   'zenoh_config = "session.json5"\nrecord_dir = "../recordings"\n')
    daemon = subprocess.Popen(
        [sys.executable, "-m", "rlgp_exec", "daemon", "--config", str(cfg)],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env={**os.environ, "ZENOH_CONFIG": ""},
    )
    try:
        line = daemon.stdout.readline() if daemon.stdout else ""
        if "daemon ready" not in line:
            daemon.kill()
            pytest.fail(f"the daemon did not start: {line} {daemon.communicate()[1]}")
        assert f"on {ep}" in line, line

        def ask(who: str, what: str, timeout_s: float = 5.0) -> dict:
            return request(ep, what, None, timeout_s=timeout_s, zenoh_config=pki[who])

        assert ask("operator", "status")["state"] == "idle"
        for who in ("rogue", "rogue_cert", "no_cert"):  # no valid certificate: nothing
            r = ask(who, "status", timeout_s=DENIED_S)
            assert not r["ok"] and "no daemon answered" in r["error"], (who, r)
        assert ask("viewer", "status")["state"] == "idle"
        r = ask("viewer", "estop", timeout_s=DENIED_S)  # a key expression its rules deny
        assert not r["ok"] and "no daemon answered" in r["error"], r
        assert ask("operator", "status")["state"] == "idle"  # the denied e-stop did not reach it
        assert ask("operator", "estop")["ok"] and ask("viewer", "status")["state"] == "estopped"
        plain = request(ep.replace("tls/", "tcp/", 1), "status", timeout_s=DENIED_S)
        assert "no daemon answered" in plain["error"], plain
    finally:
        daemon.terminate()
        _, err = daemon.communicate(timeout=30)
    assert daemon.returncode == 0, err[-2000:]
