"""Seeing the motion: ``plan --json`` carries the timed trajectory its schema documents, ``--plot`` and
``--animate`` draw it, ``replay --animate`` renders a recording; the progress display shows what happens."""

from __future__ import annotations

import io
import itertools
import json
import logging
import math
import time
from pathlib import Path
from typing import Any

import imageio.v2 as imageio
import numpy as np
import pytest

from rlgp_exec import progress
from rlgp_exec.cli import main
from rlgp_exec.demo import DemoReport, _stage
from rlgp_exec.errors import RlgpError
from rlgp_exec.executive import Recorder

ROOT = Path(__file__).resolve().parents[1]
SHELF = ROOT / "tests" / "data" / "shelf_hsr.toml"
SCHEMA = json.loads((ROOT / "docs" / "trajectory.schema.json").read_text())


def _errors(value: Any, schema: dict, where: str = "$") -> list[str]:
    """The JSON Schema keywords the trajectory schema uses (type, const, required, properties,
    additionalProperties, items, minItems, minimum, exclusiveMinimum), checked; one message per violation."""
    kinds = {"object": dict, "array": list, "string": str, "boolean": bool, "null": type(None)}
    out: list[str] = []
    if "type" in schema:
        types = schema["type"] if isinstance(schema["type"], list) else [schema["type"]]

        def is_a(t: str) -> bool:
            if t == "integer":
                return isinstance(value, int) and not isinstance(value, bool)
            if t == "number":
                return isinstance(value, int | float) and not isinstance(value, bool) and math.isfinite(value)
            return isinstance(value, kinds[t])

        if not any(is_a(t) for t in types):
            return [f"{where}: {value!r:.60} is not {types}"]
    if "const" in schema and value != schema["const"]:
        out.append(f"{where}: {value!r} != {schema['const']!r}")
    if isinstance(value, int | float) and not isinstance(value, bool):
        if "minimum" in schema and value < schema["minimum"]:
            out.append(f"{where}: {value} < {schema['minimum']}")
        if "exclusiveMinimum" in schema and value <= schema["exclusiveMinimum"]:
            out.append(f"{where}: {value} <= {schema['exclusiveMinimum']}")
    if isinstance(value, dict):
        out += [f"{where}: missing {k!r}" for k in schema.get("required", []) if k not in value]
        props = schema.get("properties", {})
        if schema.get("additionalProperties") is False:
            out += [f"{where}: unexpected {k!r}" for k in value if k not in props]
        for k, sub in props.items():
            if k in value:
                out += _errors(value[k], sub, f"{where}.{k}")
    if isinstance(value, list):
        if len(value) < schema.get("minItems", 0):
            out.append(f"{where}: {len(value)} items < {schema['minItems']}")
        if "items" in schema:
            for i, item in enumerate(value):
                out += _errors(item, schema["items"], f"{where}[{i}]")
    return out


def test_the_validator_catches_what_the_schema_forbids():
    good = {"format": "rlgp-exec/trajectory", "version": 1}
    sub = {k: SCHEMA["properties"][k] for k in good}
    assert _errors(good, {"type": "object", "properties": sub}) == []
    assert _errors({**good, "version": 2}, {"properties": sub})
    assert _errors({"x": 1}, SCHEMA)  # missing fields, an unexpected one
    assert _errors([], SCHEMA["properties"]["samples"]["properties"]["t_s"])  # minItems
    assert _errors([-1.0], SCHEMA["properties"]["samples"]["properties"]["t_s"])  # minimum
    assert _errors([1.5], SCHEMA["properties"]["samples"]["properties"]["phase"])  # an integer


@pytest.fixture(scope="module")
def planned(tmp_path_factory) -> tuple[dict, str, Path]:
    """``plan shelf --json -`` with a plot and an animation: (the JSON on stdout, stderr, the directory)."""
    out = tmp_path_factory.mktemp("plan")
    cap = pytest.MonkeyPatch()
    stdout, stderr = io.StringIO(), io.StringIO()
    cap.setattr("sys.stdout", stdout)
    cap.setattr("sys.stderr", stderr)
    try:
        rc = main(["plan", str(SHELF), "--json", "-", "--rate", "5", "--plot", str(out / "plan.png"),
                   "--animate", str(out / "plan.gif"), "--fps", "2", "--speed", "10"])
    finally:
        cap.undo()
    assert rc == 0, stderr.getvalue()
    return json.loads(stdout.getvalue()), stderr.getvalue(), out


def test_plan_json_on_stdout_is_only_json_and_the_report_goes_to_stderr(planned):
    data, err, _ = planned
    assert data["success"] and data["actions"]
    assert "shelf_hsr: rlgp found a valid plan after" in err and "s CPU (budget" in err and "s wall" in err
    assert "planning shelf_hsr with rlgp" in err  # the progress line of the stage


def test_the_trajectory_matches_its_schema_and_the_plan(planned):
    data, _, _ = planned
    traj = data["trajectory"]
    assert _errors(traj, SCHEMA) == []
    s = traj["samples"]
    t, q, dq, ph = np.array(s["t_s"]), np.array(s["q"]), np.array(s["dq"]), np.array(s["phase"])
    n = len(traj["joint_names"])
    assert q.shape == dq.shape == (len(t), n) and ph.shape == t.shape and len(t) > 2
    assert np.all(np.diff(t) >= 0) and t[0] == 0.0 and t[-1] == pytest.approx(traj["duration_s"], abs=1e-6)
    assert np.all(np.diff(t) <= 1.0 / traj["rate_hz"] + 1e-6)  # no gap wider than the rate
    assert np.all(np.diff(ph) >= 0)  # phases in order
    phases = traj["phases"]
    assert [p["index"] for p in phases] == list(range(len(phases)))
    for p in phases:  # each sample lies inside its phase's interval
        ts = t[ph == p["index"]]
        if len(ts):
            assert p["t_start_s"] - 1e-6 <= ts.min() and ts.max() <= p["t_end_s"] + 1e-6
    assert {p["action"] for p in phases if p["action"]} == set(data["actions"])
    assert any(p["grasp"] == "block" for p in phases) and any(p["release"] == "block" for p in phases)
    # the motion is continuous and rests at the ends: velocities integrate to the positions' change
    dt = np.diff(t)
    integral = np.cumsum((dq[1:] + dq[:-1]) / 2 * dt[:, None], axis=0)
    from rlgp_exec.robot import load_robot

    lin = [i for i, wraps in enumerate(load_robot(traj["robot"]).limits.continuous) if not wraps]  # no +-pi jumps
    drift = np.abs((q[1:] - q[0])[:, lin] - integral[:, lin]).max()
    assert drift < 0.05, drift
    assert np.abs(dq[0]).max() < 1e-6 and np.abs(dq[-1]).max() < 1e-6


def test_the_animation_shows_the_motion(planned):
    data, err, out = planned
    assert data["animation"] == str(out / "plan.gif")
    frames = [np.asarray(f)[..., :3] for f in imageio.mimread(out / "plan.gif")]
    duration = data["trajectory"]["duration_s"]
    assert len(frames) == math.ceil(duration / 10 * 2) + 1
    assert frames[0].shape == (300, 400, 3)
    changed = [np.abs(a.astype(int) - b.astype(int)).sum() > 0 for a, b in itertools.pairwise(frames)]
    assert sum(changed) >= len(changed) // 2, "the robot does not move in the animation"
    assert "rendering the motion to" in err


def test_the_plot_numbers_every_action(planned):
    data, err, out = planned
    assert data["plot"] == str(out / "plan.png") and (out / "plan.png").stat().st_size > 10_000
    assert "plot (base and tool paths, actions numbered)" in err


def test_the_trajectory_file_and_stdout_are_one_or_the_other(tmp_path, capsys):
    assert main(["-q", "plan", str(SHELF), "--json", "-", "--trajectory", "-"]) == 2
    assert "only one of them" in capsys.readouterr().err


def _recording(path: Path) -> Path:
    from test_recording import _write_run  # the executive's channels, as the recorder test writes them

    with Recorder(path) as rec:
        _write_run(rec, n_states=20)
    return path


def test_replay_animates_a_recording(tmp_path, capsys):
    rec = _recording(tmp_path / "run.mcap")
    assert main(["replay", str(rec), "--animate", str(tmp_path / "run.mp4"), "--fps", "10", "--speed", "0.1"]) == 0
    frames = imageio.mimread(tmp_path / "run.mp4")
    assert len(frames) == math.ceil(0.19 / 0.1 * 10) + 1  # 20 states, 0.01 s apart on the robot's clock
    assert np.abs(np.asarray(frames[0], int) - np.asarray(frames[-1], int)).sum() > 0  # the arm lifted
    assert "animation:" in capsys.readouterr().out
    assert main(["-q", "replay", str(rec), "--animate", str(tmp_path / "run.png")]) == 2


def test_plain_progress_lines_are_timestamped_and_detached_after(monkeypatch):
    buf = io.StringIO()
    d = progress.start(["rlgp_exec.test_progress"], stream=buf)
    try:
        assert not d.fancy  # not a terminal
        lg = logging.getLogger("rlgp_exec.test_progress")
        with progress.stage("over at once"):  # bad input refused at once: its error stays the only line
            pass
        with progress.stage("doing a thing"):
            lg.info("half way")
        lg.warning("a warning")
        with progress.stage("a slow step"):
            time.sleep(progress.STAGE_SAY_S + 0.3)
    finally:
        progress.stop()
    lines = buf.getvalue().splitlines()
    assert [ln.split("] ", 1)[1] for ln in lines] == ["doing a thing ...", "half way", "WARNING: a warning",
                                                      "a slow step ..."]
    assert all(ln[2] == ":" and ln[5] == ":" and "[" in ln for ln in lines)
    stamps = [float(ln.split("[", 1)[1].split(" s]", 1)[0]) for ln in lines]
    assert stamps[3] - stamps[2] < 0.5  # the slow step's start is stamped when it started, not when said
    assert logging.getLogger("rlgp_exec.test_progress").propagate  # back to the root handler
    with progress.stage("no display"):  # -q: nothing, no error
        pass


def test_rich_progress_on_a_terminal():
    buf = io.StringIO()
    d = progress.start(["rlgp_exec.test_progress"], stream=buf, fancy=True)
    try:
        with progress.stage("planning [x]"):
            logging.getLogger("rlgp_exec.test_progress").info("candidate 0 [ok]")
    finally:
        progress.stop()
    assert d.fancy and "candidate 0 [ok]" in buf.getvalue()  # markup in messages is printed, not parsed


def test_demo_stages_are_reported_as_they_run(caplog):
    report = DemoReport("x")
    events: list[str] = []

    def stage_fn() -> str:
        events.append(f"running after {len(caplog.records)} record(s)")
        return "measured"

    def failing() -> str:
        raise RlgpError("no robot")

    with caplog.at_level(logging.INFO, logger="rlgp_exec.demo"):
        assert _stage(report, "scene", stage_fn)
        assert not _stage(report, "robot", failing)
    msgs = [r.getMessage() for r in caplog.records if r.name == "rlgp_exec.demo"]
    assert events == ["running after 1 record(s)"]  # the start was logged before the stage ran
    assert msgs[0] == "scene: started" and msgs[1].startswith("scene: ok in ") and msgs[1].endswith("measured")
    assert msgs[2] == "robot: started" and "robot: FAILED" in msgs[3] and "no robot" in msgs[3]
