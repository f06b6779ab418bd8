"""The daemon's config file: the shipped example loads, bad keys and values are refused with exit 2
naming the key and what it may be, and command-line options override the file."""

from __future__ import annotations

from pathlib import Path

import pytest

from rlgp_exec.cli import build_parser, main
from rlgp_exec.cli.daemon import daemon_settings
from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.daemon_config import KEYS, DaemonConfig, load_daemon_config
from rlgp_exec.planning.registry import planner_names

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "docs" / "daemon.example.toml"


def test_the_shipped_example_loads_and_its_paths_are_relative_to_it():
    cfg = load_daemon_config(EXAMPLE)
    assert (cfg.robot, cfg.backend, cfg.planner, cfg.time_budget) == ("hsr", "sim", "rlgp", 120.0)
    assert cfg.scene == ROOT / "docs" / "../sim/scenes/sorting_hsr.toml" and cfg.scene.is_file()
    assert cfg.record_dir == ROOT / "docs" / "recordings"
    assert cfg.listen == "tcp/127.0.0.1:7450" and cfg.zenoh_config is None


@pytest.mark.parametrize(
    "text, match",
    [
        ('robots = "hsr"', r"unknown key\(s\) \['robots'\]; valid: \['robot', 'backend', 'scene'"),
        ('robot = "r2d2"', r"robot = 'r2d2': valid: \['hsr', 'pr2'\]"),
        ('backend = "ros"', r"backend = 'ros': valid: \['zenoh', 'can', 'sim'\]"),
        ('planner = "astar"', r"planner = 'astar': valid: \['rlgp'"),
        ('objects = "lidar"', r"objects = 'lidar': valid: \['camera', 'mocap', 'file'\]"),
        ("time_budget = -1", r"time_budget = -1: expected a positive number of seconds"),
        ("time_budget = true", r"time_budget = True: expected a positive number"),
        ("max_expansions = 2.5", r"max_expansions = 2.5: expected a positive whole number"),
        ("namespace = 3", r"namespace = 3: expected a string"),
        ('scene = ""', r"scene = '': expected a path"),
        ("[planner]\nname = 'rlgp'", r"planner = \{'name': 'rlgp'\}: valid"),
        ("robot = ", r"not valid TOML"),
    ],
)
def test_bad_keys_and_values_are_refused_naming_the_key_with_exit_2(tmp_path, capsys, text, match):
    cfg = tmp_path / "daemon.toml"
    cfg.write_text(text + "\n")
    with pytest.raises(RlgpError, match=match):
        load_daemon_config(cfg)
    assert main(["daemon", "--config", str(cfg)]) == 2
    err = capsys.readouterr().err
    assert str(cfg) in err


def test_command_line_options_override_the_file(tmp_path):
    cfg = tmp_path / "daemon.toml"
    cfg.write_text('robot = "pr2"\nbackend = "zenoh"\nscene = "lab.toml"\nnamespace = "lab"\n'
                   'planner = "lgp"\ntime_budget = 30.0\nzenoh_config = "z.json5"\n')
    parse = build_parser().parse_args
    args = daemon_settings(parse(["daemon", "--config", str(cfg), "--robot", "hsr", "--time-budget", "5",
                                   "--planner", planner_names()[0]]))
    assert (args.robot, args.time_budget, args.planner) == ("hsr", 5.0, planner_names()[0])  # given: theirs
    assert (args.backend, args.namespace) == ("zenoh", "lab")  # not given: the file's
    assert args.scene == str(tmp_path / "lab.toml") and args.zenoh_config == str(tmp_path / "z.json5")
    plain = daemon_settings(parse(["daemon", "--scene", "s.toml"]))  # no file: the built-in defaults
    assert (plain.robot, plain.backend, plain.namespace, plain.planner) == ("hsr", "sim", "", "rlgp")
    with pytest.raises(RlgpError, match="no scene: give --scene FILE"):
        daemon_settings(parse(["daemon"]))
    with pytest.raises(RlgpError, match=r"command line: time_budget = 0.0: expected a positive number"):
        daemon_settings(parse(["daemon", "--config", str(cfg), "--time-budget", "0"]))


def test_every_setting_is_a_daemon_option():
    opts = {a.dest for a in build_parser()._subparsers._group_actions[0].choices["daemon"]._actions}  # type: ignore[union-attr]
    assert set(KEYS) <= opts and set(KEYS) == set(vars(DaemonConfig()))
