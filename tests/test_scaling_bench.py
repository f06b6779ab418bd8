"""``bench scaling``: the object-count argument, the sweep's order, and a real sweep at N = 2 (both robots,
both planners, one seed): the JSON's shape, every record's fields, and a summary that counts the runs."""

from __future__ import annotations

import json

import pytest

from rlgp_exec.bench.scaling import ScalingJob, parse_counts, scaling_jobs
from rlgp_exec.cli import main
from rlgp_exec.errors import RlgpError

RECORD_KEYS = {"robot", "N", "seed", "planner", "success", "cpu_s", "wall_s", "planning_time_s", "n_steps",
               "n_nlp", "reason"}


def test_counts_are_a_range_or_a_list_within_the_generator():
    assert parse_counts("2..5") == (2, 3, 4, 5)
    assert parse_counts("2,4,10") == (2, 4, 10)
    for bad in ("0..3", "2..13", "a", "3..", ""):
        with pytest.raises(RlgpError, match="--n"):
            parse_counts(bad)


def test_planners_are_interleaved_for_each_robot_n_and_seed():
    jobs = scaling_jobs(["pr2", "hsr"], [2, 3], 2, ["rlgp", "gnpp"])
    assert len(jobs) == 2 * 2 * 2 * 2
    assert jobs[:3] == [
        ScalingJob("pr2", 2, 0, "rlgp"), ScalingJob("pr2", 2, 0, "gnpp"), ScalingJob("pr2", 2, 1, "rlgp")
    ]
    with pytest.raises(RlgpError, match="at least 1"):
        scaling_jobs(["pr2"], [2], 0, ["rlgp"])


def test_bench_scaling_at_n_2_writes_runs_summary_and_plot(tmp_path, capsys):
    out, png = tmp_path / "scaling.json", tmp_path / "scaling.png"
    argv = ["bench", "scaling", "--n", "2", "--seeds", "1", "--robots", "pr2,hsr", "--planners", "rlgp,gnpp",
            "--time-budget", "30", "--json", str(out), "--plot", str(png)]
    assert main(argv) == 0
    io = capsys.readouterr()
    assert "[  4/4]" in io.err  # a progress line per run
    data = json.loads(out.read_text())
    assert data["task"] == "scaling" and data["N"] == [2] and data["limits"]["time_budget_s"] == 30.0
    runs = data["runs"]
    assert [(r["robot"], r["planner"]) for r in runs] == [("pr2", "rlgp"), ("pr2", "gnpp"), ("hsr", "rlgp"),
                                                          ("hsr", "gnpp")]
    for r in runs:
        assert set(r) == RECORD_KEYS and r["N"] == 2 and r["seed"] == 0
        assert r["wall_s"] > 0 and (r["cpu_s"] is None or r["cpu_s"] > 0)
        if not r["success"]:
            assert r["reason"] and r["reason"] != "ok"
    assert set(data["summary"]) == {"rlgp", "gnpp"}
    for p, by_n in data["summary"].items():
        cell = by_n["2"]
        mine = [r for r in runs if r["planner"] == p]
        assert cell["runs"] == len(mine) == 2
        assert cell["successes"] == sum(r["success"] for r in mine)
        assert cell["success_rate"] == cell["successes"] / 2
        assert (cell["time_s_median"] is None) == (cell["successes"] == 0)
        for rb in ("pr2", "hsr"):
            assert cell["by_robot"][rb]["successes"] == sum(r["success"] for r in mine if r["robot"] == rb)
    # R-LGP sorts two blocks with either robot (each plan validated by replay in the child)
    assert data["summary"]["rlgp"]["2"]["success_rate"] == 1.0
    assert png.stat().st_size > 10_000 and data["plot"] == str(png)


def test_the_blocker_is_moved_before_the_target_it_boxes_in():
    """blocker_hsr: every closing of the fingers on the block has a blocker beside one of its faces, so the
    valid plan moves a blocker first although the goal names only the block (validated by replay)."""
    from pathlib import Path

    from rlgp_exec.planning.registry import plan
    from rlgp_exec.scene import load_scene

    scene = load_scene(Path(__file__).resolve().parents[1] / "sim" / "scenes" / "blocker_hsr.toml")
    p = plan(scene, "rlgp")
    assert p.success, p.reason
    names = [str(a) for a in p.actions]
    assert names[0] in ("(pick blocker_x)", "(pick blocker_y)") and names[-2:] == ["(pick block)", "(place block tray)"]


def test_a_run_still_planning_at_the_wall_cap_is_killed_and_recorded_failed(monkeypatch):
    """The planners' budgets are CPU time; a child stuck in a call that spends none is still ended."""
    import time

    from rlgp_exec.bench import planners as bench

    monkeypatch.setattr(bench, "run_job", lambda *_: time.sleep(60))  # in the child: no CPU spent
    record, xy = bench.run_isolated("unused.toml", "rlgp", 4, wall_timeout_s=2.0)
    assert not record["success"] and record["seed"] == 4 and xy == []
    assert record["reason"] == "timeout: still planning after 2 s wall"
