"""The command line documents itself, resolves scenes one way, keeps one exit-code policy and a clean stderr."""

from __future__ import annotations

import argparse
import logging
import os
import shutil
import subprocess
import sys
import tomllib
from importlib.metadata import version
from pathlib import Path

import pytest

from rlgp_exec.cli import build_parser, main
from rlgp_exec.cli.daemon import bad_request
from rlgp_exec.cli.flags import no_default
from rlgp_exec.errors import RlgpError
from rlgp_exec.expected_log import expected_warnings
from rlgp_exec.planning.registry import planner_names
from rlgp_exec.scene.shipped import resolve_scene, shipped_scene_dir, shipped_scenes

ROOT = Path(__file__).resolve().parents[1]
SHELF = ROOT / "tests" / "data" / "shelf_hsr.toml"
SCENE_COMMANDS = {  # a command taking a scene, its argv with {scene} in it
    "plan": ["plan", "{scene}"],
    "show": ["show", "{scene}", "--png", "{tmp}/x.png"],
    "run": ["run", "{scene}"],
    "rg": ["rg", "{scene}"],
    "perceive": ["perceive", "{scene}"],
    "bench": ["bench", "{scene}"],
    "bench reachability": ["bench", "reachability", "{scene}"],
    "demo": ["demo", "--scene", "{scene}", "--out", "{tmp}/demo"],
    "daemon": ["daemon", "--scene", "{scene}"],
}


def _subparsers(ap: argparse.ArgumentParser) -> dict[str, argparse.ArgumentParser]:
    (sub,) = [a for a in ap._actions if isinstance(a, argparse._SubParsersAction)]
    return dict(sub.choices)


def test_every_option_of_every_command_has_help_and_every_command_examples():
    ap = build_parser()
    commands = _subparsers(ap)
    assert {"plan", "run", "bench", "perceive", "sim-robot", "daemon", "request", "rg", "replay", "show",
            "demo"} <= set(commands)
    missing = [
        f"{name} {a.option_strings or a.dest}"
        for name, p in [("rlgp-exec", ap), *commands.items()]
        for a in p._actions
        if not isinstance(a, argparse._SubParsersAction) and not (a.help or "").strip()
    ]
    assert not missing, f"options without help: {missing}"
    assert not no_default(0) and no_default(False) and no_default(None) and no_default("")
    for name, p in commands.items():
        text = p.format_help()
        assert "examples:" in text and f"rlgp-exec {name}" in text.split("examples:")[1], name
        for a in p._actions:  # a default that matters is shown
            if a.option_strings and not no_default(a.default):
                assert "default" in p._get_formatter()._get_help_string(a), (name, a.option_strings)


def test_version_is_the_installed_package_version(capsys):
    with pytest.raises(SystemExit) as e:
        main(["--version"])
    assert e.value.code == 0
    assert capsys.readouterr().out.strip() == f"rlgp-exec {version('rlgp-exec')}"


def test_plan_help_lists_the_registry_planners_and_a_wrong_one_exits_2(capsys):
    text = _subparsers(build_parser())["plan"].format_help()
    flat = " ".join(text.split())
    for name in planner_names():
        assert f" {name}," in flat or f" {name} " in flat, name
    with pytest.raises(SystemExit) as e:
        main(["plan", str(SHELF), "--planner", "no_such_planner"])
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert "no_such_planner" in err and "'gnpp'" in err and "'rlgp'" in err


def test_a_scene_is_a_path_or_a_shipped_name(tmp_path, monkeypatch):
    assert resolve_scene("sorting_hsr") == shipped_scene_dir() / "sorting_hsr.toml"
    assert resolve_scene("sorting_hsr.toml") == shipped_scene_dir() / "sorting_hsr.toml"
    assert resolve_scene(SHELF) == SHELF
    own = tmp_path / "sorting_hsr.toml"  # a user's file of the same name wins where it exists
    shutil.copy(SHELF, own)
    monkeypatch.chdir(tmp_path)
    assert resolve_scene("sorting_hsr.toml") == Path("sorting_hsr.toml")
    assert set(shipped_scenes()) >= {"sorting_hsr", "table_clearing_hsr", "pick_place_pr2"}
    for bad in ("no_such_scene", "sub/sorting_hsr", str(tmp_path / "missing.toml")):
        with pytest.raises(RlgpError) as e:
            resolve_scene(bad)
        assert bad in str(e.value) and "sorting_hsr" in str(e.value) and "pick_place_pr2" in str(e.value)
    with pytest.raises(RlgpError, match="not a file"):
        resolve_scene(tmp_path)


@pytest.mark.parametrize("command", sorted(SCENE_COMMANDS))
def test_every_scene_command_refuses_an_unknown_scene_with_exit_2_listing_the_shipped(command, tmp_path, capsys):
    argv = [a.format(scene="no_such_scene", tmp=tmp_path) for a in SCENE_COMMANDS[command]]
    assert main(["-q", *argv]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert "'no_such_scene'" in line and "table_clearing_hsr" in line, line


def test_show_and_bench_take_a_shipped_name(tmp_path, capsys):
    assert main(["-q", "show", "sorting_hsr", "--png", str(tmp_path / "s.png"), "--width", "64", "--height",
                 "48"]) == 0
    assert (tmp_path / "s.png").stat().st_size > 0
    assert "sorting_hsr: wrote" in capsys.readouterr().out


def test_demo_takes_a_users_tagged_hsr_scene_and_refuses_others(tmp_path, capsys, monkeypatch):
    own = tmp_path / "my_lab.toml"
    shutil.copy(shipped_scene_dir() / "sorting_hsr.toml", own)
    untagged = tmp_path / "untagged.toml"
    untagged.write_text("\n".join(ln for ln in own.read_text().splitlines() if not ln.startswith("tag =")))
    assert tomllib.loads(untagged.read_text())  # still a scene, only without tags
    assert main(["-q", "demo", "--scene", str(shipped_scene_dir() / "sorting_pr2.toml")]) == 2
    assert "pr2 scene" in capsys.readouterr().err
    assert main(["-q", "demo", "--scene", str(untagged)]) == 2
    assert "no tagged objects" in capsys.readouterr().err
    seen: list[str] = []
    sensed: list[str] = []

    def run_demo(out, seed=0, scene_name="", objects="", foxglove=None):
        from rlgp_exec.demo import DemoReport, Stage
        from rlgp_exec.scene import load_scene

        seen.append(scene_name)
        sensed.append(objects)
        return DemoReport(load_scene(resolve_scene(scene_name)).name, [Stage("scene", True, "loaded")])

    monkeypatch.setattr("rlgp_exec.demo.run_demo", run_demo)
    assert main(["-q", "demo", "--scene", str(own), "--out", str(tmp_path / "d")]) == 0
    assert main(["-q", "demo", "--scene", "sorting_hsr", "--out", str(tmp_path / "d")]) == 0
    assert main(["-q", "demo", "--objects", "mocap", "--out", str(tmp_path / "d")]) == 0
    assert seen[:2] == [str(own), str(shipped_scene_dir() / "sorting_hsr.toml")]
    assert sensed == ["camera", "camera", "mocap"]  # the head camera unless asked


def test_gui_without_a_display_exits_2_before_any_work(monkeypatch, capsys, tmp_path):
    monkeypatch.delenv("DISPLAY", raising=False)
    for argv in (["plan", str(SHELF), "--gui"], ["run", str(SHELF), "--gui"], ["demo", "--gui"],
                 ["replay", str(tmp_path / "none.mcap"), "--gui"]):
        assert main(["-q", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert "$DISPLAY" in err and len(err.strip().splitlines()) == 1, err



def test_gui_with_a_display_no_x_server_answers_exits_2_before_any_work(monkeypatch, capsys):
    """A stale $DISPLAY (a closed ssh -X session): refused up front, not after a plan, by PyBullet."""
    monkeypatch.setenv("DISPLAY", ":87")  # no /tmp/.X11-unix/X87 here
    for argv in (["plan", str(SHELF), "--gui"], ["run", str(SHELF), "--gui"], ["demo", "--gui"]):
        assert main(["-q", *argv]) == 2, argv
        err = capsys.readouterr().err
        assert "no X server answers on DISPLAY=:87" in err and "planning" not in err, err


@pytest.mark.parametrize("extra, says", [
    (["--animate", "motion.avi"], ".gif or .mp4"),
    (["--animate", "motion.gif", "--fps", "0"], "must be positive"),
    (["--animate", "motion.gif", "--speed", "-1"], "must be positive"),
    (["--rate", "0"], "--rate 0.0 Hz"),
])  # fmt: skip
def test_bad_output_options_exit_2_before_planning(extra, says, capsys):
    assert main(["-q", "plan", str(SHELF), *extra]) == 2
    err = capsys.readouterr().err
    assert says in err and "planning" not in err


def test_request_exit_codes(monkeypatch, capsys):
    """Bad input 2 (no literals, a malformed or unknown goal), refused now 1, done 0 - against a live daemon."""
    from rlgp_exec.executive.daemon import Daemon, DaemonOptions
    from rlgp_exec.executive.runner import RunOptions
    from rlgp_exec.scene import load_scene
    from rlgp_exec.sim.robot_process import free_endpoint

    monkeypatch.delenv("ZENOH_CONFIG", raising=False)
    assert main(["-q", "request", "goal"]) == 2
    assert main(["-q", "request", "status", "(on a b)"]) == 2
    ep = free_endpoint()
    daemon = Daemon(load_scene(SHELF), RunOptions(backend="sim"), DaemonOptions(ep, "clitest"))
    daemon.start()
    try:
        base = ["-q", "request", "--endpoint", ep, "--namespace", "clitest"]
        assert main([*base[:2], "status", *base[2:]]) == 0
        assert main([*base[:2], "goal", "(on block no_such_place)", *base[2:]]) == 2
        assert main([*base[:2], "goal", "(on block", *base[2:]]) == 2
        assert main([*base[:2], "estop", *base[2:]]) == 0
        assert main([*base[:2], "goal", "(on block tray)", *base[2:]]) == 1  # well-formed, refused while e-stopped
        out = capsys.readouterr().out
        assert "no_such_place" in out and "ESTOPPED" in out
    finally:
        daemon.stop()
    assert bad_request("goal: literals[0]: unknown object 'x'")
    assert not bad_request("goal refused: the executive is ESTOPPED; an operator must send rearm first")
    assert not bad_request("no daemon answered at tcp/127.0.0.1:1 within 5.0 s")


def test_expected_warnings_are_logged_at_info(caplog):
    lg = logging.getLogger("rlgp_exec.test_expected")
    with caplog.at_level(logging.INFO):
        with expected_warnings(["rlgp_exec.test_expected"]):
            lg.warning("e-stop latched")
            lg.error("a real error")
        lg.warning("after the block")
    levels = [(r.getMessage(), r.levelname) for r in caplog.records if r.name == "rlgp_exec.test_expected"]
    assert levels == [("e-stop latched", "INFO"), ("a real error", "ERROR"), ("after the block", "WARNING")]
    caplog.clear()
    with caplog.at_level(logging.WARNING), expected_warnings(["rlgp_exec.test_expected"]):
        lg.warning("dropped where INFO is off")
    assert not [r for r in caplog.records if r.name == "rlgp_exec.test_expected"]


def test_no_pybullet_banner_on_stderr(tmp_path):
    env = {**os.environ, "PYTHONPATH": str(ROOT), "OPENBLAS_NUM_THREADS": "1"}
    r = subprocess.run(
        [sys.executable, "-m", "rlgp_exec", "-q", "show", "sorting_hsr", "--png", str(tmp_path / "a.png"), "--width",
         "64", "--height", "48"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=120,
    )
    assert r.returncode == 0, r.stderr
    assert r.stderr == "", r.stderr
    assert (tmp_path / "a.png").is_file()


def test_a_worker_outliving_its_stop_ends_the_process_without_leak_dumps(tmp_path):
    """A thread still holding native objects at exit (a daemon's worker whose join timed out) makes nanobind
    print its leak dumps at interpreter shutdown; the daemon command ends the process first, its code kept."""
    code = """
import threading, time, ruckig
from rlgp_exec.cli.daemon import exit_if_threads_linger
def hold():
    kept = (ruckig.Ruckig(3, 0.01), ruckig.InputParameter(3))
    time.sleep(60)
threading.Thread(target=hold, name="executive", daemon=True).start()
time.sleep(0.2)
print("stopped", flush=True)
if {linger}:
    exit_if_threads_linger(3, "test")
"""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    runs = [subprocess.run([sys.executable, "-c", code.format(linger=x)], env=env, capture_output=True, text=True,
                           timeout=60) for x in (False, True)]
    assert "nanobind: leaked" in runs[0].stderr  # what a plain exit prints: the test shows the case
    assert runs[1].returncode == 3 and runs[1].stdout == "stopped\n" and "leaked" not in runs[1].stderr


@pytest.mark.parametrize("goal", ["(on block", "(on block no_such_place)"])
def test_run_with_a_bad_goal_exits_2_and_says_why(goal, capsys):
    assert main(["-q", "run", str(SHELF), "--goal", goal]) == 2
    out = capsys.readouterr().out
    assert "invalid_goal" in out and goal.split()[-1].strip("()") in out
