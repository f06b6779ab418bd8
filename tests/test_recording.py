"""Recordings under damage: every prefix of a recording reads and replays what it holds, crafted and
fuzzed records are refused with a RecordingError naming the record, and a recorder whose file fails
(a file-size limit, /dev/full, a closed descriptor) stops, says why once, and leaves a readable prefix."""

from __future__ import annotations

import copy
import itertools
import json
import os
import random
import resource
import struct
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import CompressionType, Writer

from rlgp_exec.cli import main
from rlgp_exec.errors import RlgpError
from rlgp_exec.executive import ExecState, Recorder, StateMachine, read_recording
from rlgp_exec.executive.recorder import MAGIC, MAX_RECORD, RecordingError
from rlgp_exec.executive.replay import ReplayInput, load_replay, replay
from rlgp_exec.executive.ros_record import ROS_CHANNELS
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene, scene_to_dict

ROOT = Path(__file__).resolve().parents[1]
SCENE = ROOT / "tests" / "data" / "shelf_hsr.toml"


def _write_run(rec: Recorder, n_states: int = 3) -> None:
    """What the executive writes over a short task, on every channel, in its order and shapes."""
    scene = load_scene(SCENE)
    model = load_robot("hsr")
    names = list(model.joint_names[3:])
    sm = StateMachine()
    sm.listeners.append(lambda tr: rec.write("/transitions", tr.as_dict(), tr.t_wall))
    sm.to(ExecState.SENSING, "task")
    block = np.eye(4)
    block[:3, 3] = scene.object("block").T[:3, 3]
    rec.write("/detections", {"source": "SimMocap", "poses": {"block": block}})
    rec.write("/scene", scene_to_dict(scene))
    sm.to(ExecState.PLANNING)
    q0 = model.home(scene.robot.base)
    path = np.linspace(q0, q0 + 0.05, 3)
    rec.write("/plan", {"success": True, "actions": ["(pick block)"],
                        "phases": [{"path": path, "held": None, "grasp": "block", "release": None}]})
    sm.to(ExecState.EXECUTING, "(pick block)")
    lift = names.index("arm_lift_joint") + 3
    for k in range(n_states):
        q = q0.copy()
        q[lift] += 0.01 * k
        rec.write("/command", {"names": names, "q": q[3:], "dq": np.zeros(len(names)), "base_twist": [0.1, 0.0, 0.0],
                               "q_model": q, "accepted": True, "refused": ""})
        rec.write("/robot_state", {"stamp": 0.01 * k, "names": names, "q": q[3:], "dq": np.zeros(len(names)),
                                   "base": [0.001 * k, 0.0, 0.0], "base_velocity": [0.1, 0.0, 0.0],
                                   "gripper": 0.0, "estopped": False, "faults": [], "i": k})
    rec.write("/events", {"kind": "result", "status": "succeeded", "detail": "goal met"})


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("rec") / "run.mcap"
    with Recorder(path) as rec:
        _write_run(rec)
    return path


def _record_ends(data: bytes) -> list[int]:
    """The offsets where the file's records end (8: the opening magic), walking the MCAP framing."""
    ends, off = [8], 8
    while off + 9 <= len(data) - 8:
        off += 9 + struct.unpack_from("<Q", data, off + 1)[0]
        ends.append(off)
    return ends


def _cuts(data: bytes, ends: list[int], edge: int = 64) -> list[int]:
    """Every length of ``data``, longest first, except inside a record's body more than ``edge`` bytes
    from both of its ends: a cut there is the same case as one ``edge`` bytes in (a body cut off), and
    the viewer channels' large records (the URDF) would make every-byte cuts quadratic for nothing."""
    keep = set(range(len(data) + 1))
    for start, end in itertools.pairwise(ends):
        keep -= set(range(start + 9 + edge, end - edge))
    return sorted(keep, reverse=True)


def test_the_reader_agrees_with_the_mcap_library(recording):
    rec = read_recording(recording)
    with open(recording, "rb") as f:
        theirs = [(ch.topic, m.log_time / 1e9, json.loads(m.data))
                  for _, ch, m in make_reader(f).iter_messages() if ch.message_encoding == "json"]
        f.seek(0)
        viewer: dict[str, int] = {}
        for _, ch, _ in make_reader(f).iter_messages():
            if ch.message_encoding != "json":
                viewer[ch.topic] = viewer.get(ch.topic, 0) + 1
    assert rec.complete and rec.truncated_at is None and rec.ending == "complete"
    assert list(rec.messages) == theirs
    assert {tp for tp, _, _ in rec.messages} == {"/robot_state", "/command", "/transitions", "/events", "/plan",
                                                  "/scene", "/detections"}
    assert dict(rec.derived) == viewer and set(viewer) == set(ROS_CHANNELS)


def test_every_prefix_reads_its_complete_records_and_replays_or_is_refused(recording, tmp_path):
    data = recording.read_bytes()
    full = read_recording(recording)
    ends = _record_ends(data)
    assert ends[-1] == len(data) - 8  # the walk lands on the footer's end: the closing magic follows
    header_end = ends[1]
    msg_ends = [o + 9 + struct.unpack_from("<Q", data, o + 1)[0] for o in full.offsets]
    first_scene = msg_ends[[tp for tp, _, _ in full.messages].index("/scene")]
    cut_file = tmp_path / "cut.mcap"
    cut_file.write_bytes(data)
    replayed: dict[int, list[int]] = {}  # messages: the first and last cut that hold them (replayed)
    for cut in _cuts(data, ends):
        os.truncate(cut_file, cut)  # shorter and shorter: one file, not one per cut
        n = sum(e <= cut for e in msg_ends)
        try:
            inp = load_replay(cut_file)
        except RecordingError as e:
            if cut < header_end:
                assert "not a readable MCAP recording" in str(e) and f"ends at byte {cut}," in str(e), (cut, e)
            else:
                assert cut < first_scene and "no /scene message" in str(e) and f"{n} messages" in str(e), (cut, e)
            assert str(cut_file) in str(e)
            continue
        assert cut >= first_scene, cut
        rec = inp.recording
        assert rec.messages == full.messages[:n], cut
        assert rec.complete == (cut == len(data))
        if not rec.complete:
            assert rec.truncated_at == max(e for e in ends if e <= cut), cut
            assert (f"truncated at byte {rec.truncated_at}" if rec.truncated_at < cut else "unfinished") in rec.ending
        recorded = [dict(zip(d["names"], d["q"], strict=True)) for _, d in rec.topic("/robot_state")]
        assert [s.joints for s in inp.states] == recorded
        replayed.setdefault(n, [cut, cut])[0] = cut
    for n, cut in ((n, cut) for n, cuts in replayed.items() for cut in cuts):
        cut_file.write_bytes(data[:cut])
        report = replay(cut_file, step=1)
        assert report.messages == n and report.collisions == ()
        assert report.states == sum(tp == "/robot_state" for tp, _, _ in full.messages[:n])
        assert report.complete == (cut == len(data))
        assert ("truncated at byte" in report.text()) == (cut not in ends and cut != len(data)), report.text()
    assert len(replayed) == len(full.messages) - full.messages.index(next(m for m in full.messages if m[0] == "/scene"))


def test_cli_replays_a_cut_recording_and_refuses_garbage_with_exit_2(recording, tmp_path, capsys):
    data = recording.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: len(data) - 300])  # inside the summary section: every message is there
    out_json = tmp_path / "out.json"
    assert main(["replay", str(cut), "--json", str(out_json)]) == 0
    out = capsys.readouterr().out
    assert "truncated at byte" in out and "result: succeeded" in out
    summary = json.loads(out_json.read_text())
    assert summary["complete"] is False and summary["truncated_at"] in _record_ends(data)
    bad = tmp_path / "bad.mcap"
    bad.write_bytes(data[: _record_ends(data)[3]] + b"\xff" * 40)  # a record claiming 2^64-1 bytes
    assert main(["replay", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.startswith("rlgp-exec replay: error: ") and str(bad) in err and "Traceback" not in err


# ---------------------------------------------------------------------------------- crafted records
def _mcap(path: Path, messages: list[tuple[str, bytes]], *, scene: bool = True, chunked: bool = False) -> Path:
    """A valid MCAP file (the mcap library's writer) holding ``messages`` (topic, payload bytes) after a
    good /scene message."""
    with open(path, "wb") as f:
        w = Writer(f, use_chunking=chunked, compression=CompressionType.NONE)
        w.start(profile="rlgp-exec", library="test")
        channels: dict[str, int] = {}
        sid = w.register_schema(name="s", encoding="jsonschema", data=b"{}")
        items = ([("/scene", json.dumps(scene_to_dict(load_scene(SCENE))).encode())] if scene else []) + messages
        for topic, payload in items:
            if topic not in channels:
                channels[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
            w.add_message(channels[topic], log_time=1, data=payload, publish_time=1)
        w.finish()
    return path


def _state(**over) -> bytes:
    d = {"stamp": 0.0, "names": ["arm_lift_joint"], "q": [0.1], "base": [0.0, 0.0, 0.0]}
    d.update(over)
    return json.dumps({k: v for k, v in d.items() if v is not None}).encode()


MSG = r"Message record at byte \d+: "
STATE = r"/robot_state message at byte \d+: "
CRAFTED = {  # case: (topic, payload, what the error says)
    "not JSON": ("/events", b'{"kind": "result", "status": ', MSG + r"\(/events\) payload is not JSON"),
    "not UTF-8": ("/events", b'{"kind": "\xff"}', MSG + r"\(/events\) payload is not JSON"),
    "a JSON array": ("/robot_state", b"[1, 2]", MSG + r"\(/robot_state\) payload is a JSON list, expected an object"),
    "nested too deep": ("/plan", b"[" * 200_000 + b"]" * 200_000, MSG + r"\(/plan\) payload is not JSON: Recursion"),
    "a missing field": ("/robot_state", _state(base=None), STATE + "missing field 'base'"),
    "a string for q": ("/robot_state", _state(q="0.1"), STATE + "q: expected a list of 1 numbers"),
    "q not matching names": ("/robot_state", _state(q=[0.1, 0.2]), STATE + "q: expected a list of 1 numbers"),
    "a NaN base": ("/robot_state", _state(base=[0.0, float("nan"), 0.0]), STATE + r"base\[1\]: expected a finite"),
    "a far base": ("/robot_state", _state(base=[0.0, 1e300, 0.0]), STATE + r"base\[1\]: .* of at most 10000 in size"),
    "a huge integer": ("/robot_state", _state(stamp=10**400), STATE + "stamp: expected a finite number, got 1000"),
    "a 3x3 pose": ("/detections", json.dumps({"poses": {"block": np.eye(3).tolist()}}).encode(),
                   r"/detections message at byte \d+: poses\['block'\]: expected a 4x4 matrix"),
    "a bad transition": ("/transitions", b'{"to": 3}', r"/transitions message at byte \d+: to: expected a state"),
    "an unknown topic": ("/camera", b"{}", r"Channel record at byte \d+: channel \d+: topic '/camera' is not a"),
}


@pytest.mark.parametrize("case", sorted(CRAFTED))
def test_crafted_messages_are_refused_naming_the_record(tmp_path, case):
    topic, payload, pattern = CRAFTED[case]
    path = _mcap(tmp_path / "crafted.mcap", [(topic, payload)])
    with pytest.raises(RecordingError, match=pattern) as e:
        load_replay(path)
    assert str(e.value).startswith(str(path))


def test_a_bad_scene_is_refused_naming_the_message_and_field(tmp_path):
    bad = b'{"scene": {"name": "x", "robot": "r2d2"}, "robot": {}}'
    path = _mcap(tmp_path / "scene.mcap", [("/scene", bad)], scene=False)
    with pytest.raises(RlgpError, match=r"scene\.mcap: /scene message at byte \d+: \[scene\]\.robot"):
        load_replay(path)


def _framed(op: int, body: bytes) -> bytes:
    return struct.pack("<BQ", op, len(body)) + body


def _text(s: bytes) -> bytes:
    return struct.pack("<I", len(s)) + s


HEADER = _framed(0x01, _text(b"rlgp-exec") + _text(b"test"))
SCHEMA = _framed(0x03, struct.pack("<H", 1) + _text(b"s") + _text(b"jsonschema") + _text(b"{}"))


def _channel(cid: int, topic: bytes, schema: int = 1, enc: bytes = b"json") -> bytes:
    return _framed(0x04, struct.pack("<HH", cid, schema) + _text(topic) + _text(enc) + _text(b""))


def _message(cid: int, payload: bytes = b"{}") -> bytes:
    return _framed(0x05, struct.pack("<HIQQ", cid, 0, 1, 1) + payload)


FRAMED = {
    "a record larger than allowed": (HEADER + struct.pack("<BQ", 0x05, MAX_RECORD + 1) + b"x" * 64,
                                     rf"Message record at byte 38: declares {MAX_RECORD + 1} bytes, more than"),
    "a string longer than its record": (HEADER + SCHEMA + _framed(0x04, struct.pack("<HHI", 1, 1, 2**31) + b"/scene"),
                                        r"Channel record at byte \d+: topic needs 2147483648 bytes, the record has 6"),
    "an undeclared channel": (HEADER + SCHEMA + _channel(1, b"/events") + _message(7),
                              r"Message record at byte \d+: channel 7, which no Channel record"),
    "an undeclared schema": (HEADER + _channel(1, b"/events", schema=42), r"refers to schema 42, which no Schema"),
    "a channel declared twice": (HEADER + SCHEMA + _channel(1, b"/events") + _channel(1, b"/plan"),
                                 r"channel 1 declared again as '/plan', first as '/events'"),
    "a non-JSON channel": (HEADER + SCHEMA + _channel(1, b"/events", enc=b"cdr"), r"message encoding 'cdr'"),
    "schema id 0": (HEADER + _framed(0x03, struct.pack("<H", 0) + _text(b"s") + _text(b"") + _text(b"")),
                    r"Schema record at byte \d+: schema id 0 is reserved"),
    "a second header": (HEADER + HEADER, r"Header record at byte 38: a second Header"),
    "no header": (SCHEMA, r"not a readable MCAP recording: its first record \(byte 8\) is opcode 0x03, not a Header"),
    "a message after DataEnd": (HEADER + SCHEMA + _channel(1, b"/events") + _framed(0x0F, b"\0" * 4) + _message(1),
                                r"after the DataEnd record"),
    "not MCAP": (None, r"does not start with the MCAP magic"),
}


@pytest.mark.parametrize("case", sorted(FRAMED))
def test_malformed_records_are_refused_naming_the_offset(tmp_path, case):
    body, pattern = FRAMED[case]
    path = tmp_path / "framed.mcap"
    path.write_bytes(b"PK\x03\x04" + b"\0" * 40 if body is None else MAGIC + body)
    with pytest.raises(RecordingError, match=pattern) as e:
        read_recording(path)
    assert str(e.value).startswith(str(path))


def test_chunked_files_and_trailing_bytes_are_refused(tmp_path):
    chunked = _mcap(tmp_path / "chunked.mcap", [("/events", b"{}")], chunked=True)
    with pytest.raises(RecordingError, match=r"Chunk record at byte \d+: chunked"):
        read_recording(chunked)
    tail = tmp_path / "tail.mcap"
    tail.write_bytes(_mcap(tmp_path / "ok.mcap", []).read_bytes() + b"more")
    with pytest.raises(RecordingError, match="4 bytes after the closing magic"):
        read_recording(tail)


JUNK = (None, True, "x", "0.1", -1, 10**30, 1e308, float("nan"), [], {}, [[]], {"a": 1}, [1.0] * 3, [[0.0] * 4] * 3)


def _mutate_json(rng: random.Random, obj: object) -> None:
    """Delete or replace (by a value of another type or shape) one item of ``obj``: a top-level field half
    the time, else one up to 3 levels down."""
    node = obj
    for _ in range(0 if rng.random() < 0.5 else rng.randint(1, 3)):
        kids = [k for k in (node.values() if isinstance(node, dict) else node) if isinstance(k, dict | list) and k]
        if not kids:
            break
        node = rng.choice(kids)
    if isinstance(node, dict) and node:
        key = rng.choice(list(node))
    elif isinstance(node, list) and node:
        key = rng.randrange(len(node))
    else:
        return
    if rng.random() < 0.4:
        del node[key]  # type: ignore[arg-type]
    else:
        node[key] = copy.deepcopy(rng.choice(JUNK))  # type: ignore[index]


def _check_input(inp: ReplayInput) -> None:
    """What the replay takes from load_replay is what it is declared to be."""
    assert all(isinstance(t, str) for t in inp.transitions + inp.results)
    for st in inp.states:
        assert all(type(v) is float and np.isfinite(v) for v in (st.stamp, *st.base, *st.joints.values()))
        assert all(isinstance(n, str) for n in st.joints)
    for _, poses in inp.detections:
        assert all(T.shape == (4, 4) and np.isfinite(T).all() for T in poses.values())


def test_fuzzed_recordings_raise_only_recording_errors_in_bounded_time_and_memory(recording, tmp_path):
    data = recording.read_bytes()
    full = read_recording(recording)
    rng = random.Random(20240601)
    ends = _record_ends(data)
    path = tmp_path / "fuzz.mcap"
    outcomes = {"read": 0, "refused": 0, "replayed": 0}
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    worst = 0.0
    replayed_topics = [k for k, (tp, _, _) in enumerate(full.messages) if tp != "/command" and tp != "/plan"]
    for i in range(800):
        b = bytearray(data)
        kind = min(i % 10, 7)  # 7, a damaged message, 3 times in 10
        if kind == 0:  # bit flips
            for _ in range(rng.randint(1, 8)):
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif kind == 1:  # a truncation, then a flip before it
            b = b[: rng.randrange(len(b))]
            if b:
                b[rng.randrange(len(b))] ^= 1 << rng.randrange(8)
        elif kind == 2:  # a splice: a slice of the file copied elsewhere
            s = rng.randrange(len(b))
            piece = b[s : s + rng.randint(1, 400)]
            at = rng.randrange(len(b))
            b[at:at] = piece
        elif kind == 3:  # a whole record dropped or repeated
            k = rng.randrange(1, len(ends) - 1)
            rec_bytes = b[ends[k - 1] : ends[k]]
            b[ends[k - 1] : ends[k]] = rec_bytes * rng.choice([0, 2])
        elif kind == 4:  # a record's length field set to a random 64-bit value, large or near its own
            k = rng.randrange(len(ends) - 1)
            old = struct.unpack_from("<Q", b, ends[k] + 1)[0]
            new = rng.choice([rng.getrandbits(64), max(0, old + rng.randint(-20, 20))])
            struct.pack_into("<Q", b, ends[k] + 1, new)
        elif kind == 5:  # random bytes over a span
            s = rng.randrange(len(b))
            n = rng.randint(1, 32)
            b[s : s + n] = rng.randbytes(n)
        elif kind == 6:  # bits flipped in a record's fields (ids, string lengths, times), not its payload
            k = rng.randrange(len(ends) - 1)
            b[ends[k] + 9 + rng.randrange(min(24, ends[k + 1] - ends[k] - 9))] ^= 1 << rng.randrange(8)
        else:  # a message the replay reads, its JSON with a field missing or of another type or shape, re-framed
            o = full.offsets[rng.choice(replayed_topics)]
            n = struct.unpack_from("<Q", b, o + 1)[0]
            msg = json.loads(bytes(b[o + 31 : o + 9 + n]))
            _mutate_json(rng, msg)
            payload = json.dumps(msg).encode()
            b[o : o + 9 + n] = struct.pack("<BQ", 0x05, 22 + len(payload)) + b[o + 9 : o + 31] + payload
        path.write_bytes(bytes(b))
        t = time.process_time()  # CPU, not wall-clock: other processes do not count
        try:
            inp = load_replay(path)
            _check_input(inp)
            outcomes["read"] += 1
            if outcomes["replayed"] < 12 and kind == 7:  # PyBullet takes what the checks let through
                replay(path, step=1)
                outcomes["replayed"] += 1
        except RlgpError as e:  # RecordingError, or a SceneError for a damaged /scene: the project's own
            assert str(path) in str(e), e
            outcomes["refused"] += 1
        worst = max(worst, time.process_time() - t)
    assert outcomes["read"] > 50 and outcomes["refused"] > 50 and outcomes["replayed"] == 12, outcomes
    assert worst < 2.0, f"one mutant took {worst:.2f} s of CPU"  # (~5 ms each: a blow-up, not a slow machine)
    assert resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0 < 200_000  # [kB]


# ---------------------------------------------------------------------------------- write failures
FSIZE_CHILD = textwrap.dedent("""
    import json, resource, signal, sys
    from rlgp_exec.executive.recorder import Recorder
    from tests.test_recording import _write_run
    path, limit = sys.argv[1], int(sys.argv[2])
    signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit: EFBIG, not a killed process
    resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    calls = []
    rec = Recorder(path, on_error=calls.append)
    _write_run(rec)
    given, n_bytes = rec.n_messages, rec.n_bytes
    for i in range(200):  # the control loop goes on: every write returns, none is recorded
        rec.write("/robot_state", {"i": i})
    rec.close()
    print(json.dumps({"calls": calls, "error": rec.error, "n_bytes": n_bytes, "given": given,
                      "later": [rec.n_messages, rec.n_bytes]}))
""")


@pytest.mark.parametrize("topic", ["/scene", "/robot_state"])
def test_a_file_size_limit_stops_the_recording_once_and_leaves_a_replayable_prefix(tmp_path, topic):
    """RLIMIT_FSIZE: the kernel takes part of a write, then refuses the rest (EFBIG), as a full disk does.
    The limit falls 20 bytes into the first ``topic`` message (its record is longer)."""
    full = read_recording(_full_run(tmp_path))
    k = [tp for tp, _, _ in full.messages].index(topic)
    limit = full.offsets[k] + 20
    path = tmp_path / "limited.mcap"
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", FSIZE_CHILD, str(path), str(limit)], cwd=ROOT, env=env,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    res = json.loads(out.stdout)
    assert len(res["calls"]) == 1 and res["calls"][0] == res["error"]
    assert "File too large" in res["error"] and str(path) in res["error"]
    assert out.stderr.count(res["error"]) == 1, out.stderr  # logged once (by logging's last-resort handler)
    assert res["later"] == [res["given"], res["n_bytes"]]  # later writes and close() did nothing
    assert path.stat().st_size == res["n_bytes"] == limit  # every byte the kernel took is kept
    rec = read_recording(path)
    # (the cut record starts a few bytes off full.offsets[k]: a transition's wall time varies in length)
    assert not rec.complete and rec.truncated_at < limit
    assert f"truncated at byte {rec.truncated_at}: the record there is cut off after {limit - rec.truncated_at} bytes" \
        in rec.ending
    assert [m[0] for m in rec.messages] == [m[0] for m in full.messages[:k]]  # the messages before the cut
    assert [m[2] for m in rec.messages if m[0] != "/transitions"] == [  # (a transition holds its wall time)
        m[2] for m in full.messages[:k] if m[0] != "/transitions"]
    if topic == "/scene":
        with pytest.raises(RecordingError, match="no /scene message"):
            load_replay(path)
    else:
        report = replay(path)
        assert report.messages == k and report.states == 0 and not report.complete


def _full_run(tmp_path: Path) -> Path:
    with Recorder(tmp_path / "full.mcap") as rec:
        _write_run(rec)
    return rec.path


def test_dev_full_is_refused_when_the_recorder_opens_it():
    with pytest.raises(RecordingError, match=r"^cannot write recording /dev/full: No space left on device"):
        Recorder("/dev/full")


@pytest.mark.parametrize("fault", ["closed", "/dev/full"])
def test_a_failing_descriptor_stops_the_recording_and_the_callback_may_write(tmp_path, caplog, fault):
    """The recorder's descriptor closed under it (EBADF), or made /dev/full's (ENOSPC from the kernel,
    as a disk that fills up mid-run) after the /scene message."""
    path = tmp_path / "failing.mcap"
    calls: list[str] = []
    rec = Recorder(path)

    def on_error(reason: str) -> None:  # as the executive's would: raise a fault event, recorded
        calls.append(reason)
        rec.write("/events", {"kind": "fault", "detail": reason})
        raise RuntimeError("a failing callback")

    rec.on_error = on_error
    rec.write("/scene", scene_to_dict(load_scene(SCENE)))
    (fd,) = [int(n) for n in os.listdir("/proc/self/fd") if os.path.realpath(f"/proc/self/fd/{n}") == str(path)]
    if fault == "closed":
        os.close(fd)
    else:
        full = os.open("/dev/full", os.O_WRONLY)
        os.dup2(full, fd)
        os.close(full)
    done = threading.Event()

    def control_loop() -> None:
        for i in range(50):
            rec.write("/transitions", {"to": "executing", "i": i})
        rec.close()
        done.set()

    threading.Thread(target=control_loop, daemon=True).start()
    assert done.wait(10.0), "a write blocked (the callback ran under the recorder's lock?)"
    if fault == "/dev/full":  # the recorder released its descriptor
        assert os.path.realpath(f"/proc/self/fd/{fd}") != "/dev/full"
    assert len(calls) == 1 and rec.error == calls[0]
    assert ("Bad file descriptor" if fault == "closed" else "No space left on device") in calls[0]
    errors = [r for r in caplog.records if r.levelname == "ERROR" and r.name.endswith("recorder")]
    assert [r.getMessage() for r in errors][:1] == [rec.error] and "callback failed" in errors[1].getMessage()
    assert len(errors) == 2
    R = read_recording(path)
    assert [tp for tp, _, _ in R.messages] == ["/scene"] and R.truncated_at == path.stat().st_size
    assert load_replay(path).scene.name == "shelf_hsr"
