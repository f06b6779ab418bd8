"""Planner limits: ``PlanLimits`` refuses bad values, both planners obey the budget and the expansion cap
handed through ``registry.plan``, the executive passes them on, and the CLI's options, errors and
progress lines."""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import pytest

from rlgp_exec.cli import main
from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.limits import PlanLimits
from rlgp_exec.planning.registry import plan
from rlgp_exec.scene import load_scene

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"
SORTING = SCENES / "sorting_hsr.toml"


@pytest.mark.parametrize(
    "kw", [{"time_budget_s": 0.0}, {"time_budget_s": -3.0}, {"time_budget_s": math.nan}, {"time_budget_s": True},
           {"max_expansions": 0}, {"max_expansions": 2.5}, {"max_expansions": -1}],
)
def test_limits_refuse_what_is_not_a_positive_number(kw):
    with pytest.raises(RlgpError, match="must be a positive"):
        PlanLimits(**kw)


def test_limits_default_to_the_planners_own():
    assert PlanLimits().as_dict() == {"time_budget_s": None, "max_expansions": None}
    assert PlanLimits(5, 100).as_dict() == {"time_budget_s": 5, "max_expansions": 100}


@pytest.mark.parametrize("planner", ["rlgp", "gnpp"])
def test_a_small_time_budget_ends_planning_with_a_budget_reason(planner):
    p = plan(load_scene(SORTING), planner, limits=PlanLimits(time_budget_s=0.3))
    assert not p.success and p.reason.startswith("budget: 0.3 s CPU spent"), p.reason


def test_rlgp_search_stops_at_the_expansion_cap():
    p = plan(load_scene(SORTING), "rlgp", limits=PlanLimits(max_expansions=1))
    assert not p.success and p.nodes_expanded <= 1
    assert "no symbolic plan within the search budget" in p.reason, p.reason


def test_gnpp_logic_search_stops_at_the_expansion_cap():
    p = plan(load_scene(SORTING), "gnpp", limits=PlanLimits(max_expansions=1))
    assert not p.success and "expansion budget hit" in p.reason, p.reason


def test_the_executive_plans_with_the_limits_it_is_given():
    from rlgp_exec.executive.runner import RunOptions, run_task

    result, ex = run_task(load_scene(SORTING), RunOptions(limits=PlanLimits(max_expansions=1)), None)
    assert ex.limits == PlanLimits(max_expansions=1)
    assert not result.ok and "search budget" in result.detail, result.detail


@pytest.mark.parametrize(
    "argv, words",
    [
        (["plan", str(SORTING), "--time-budget", "0"], "time budget 0.0 s: must be a positive"),
        (["run", str(SORTING), "--max-expansions", "0"], "max expansions 0: must be a positive"),
        (["daemon", "--scene", str(SORTING), "--time-budget", "-1"], "time_budget = -1.0: expected a positive"),
        (["bench", "scaling", "--n", "1..99"], "object counts must lie in 1..12"),
        (["bench", "scaling", "--n", "2", "--planners", "nope"], "unknown planner(s) ['nope']; valid:"),
        (["bench", "scaling", "--n", "2", "--robots", "r2d2"], "valid: ['pr2', 'hsr']"),
    ],
)
def test_bad_options_exit_2_naming_what_is_wrong(argv, words, capsys):
    assert main(argv) == 2
    assert words in capsys.readouterr().err


def _progress(text: str) -> list[str]:
    """The progress display's lines (not a terminal: ``HH:MM:SS [elapsed s] message``), their messages."""
    return [m.group(1) for m in re.finditer(r"^\d\d:\d\d:\d\d \[ *[\d.]+ s\] (.*)$", text, re.M)]


def test_progress_goes_to_stderr_and_quiet_turns_it_off(tmp_path, capsys):
    out = tmp_path / "plan.json"
    argv = ["plan", str(SORTING), "--time-budget", "0.3", "--json", str(out)]
    assert main(argv) == 1
    io = capsys.readouterr()
    assert "rlgp: budget: 0.3 s CPU spent" in " ".join(_progress(io.err)) and not _progress(io.out)
    assert json.loads(out.read_text())["success"] is False
    assert main(["-q", *argv]) == 1
    assert not _progress(capsys.readouterr().err)


def test_progress_shows_each_candidate_and_its_outcome(capsys):
    assert main(["plan", str(SORTING)]) == 0
    err = capsys.readouterr().err
    lines = [ln for ln in _progress(err) if ln.startswith("rlgp candidate ")]
    # each candidate twice: when its geometry starts (its length and search effort), and how it ended
    assert lines and lines[0].startswith("rlgp candidate 0: 4 actions after "), err
    assert lines[1].startswith("rlgp candidate 0 (pick ") and lines[-1].endswith(": ok"), err
