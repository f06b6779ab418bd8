"""The planner bench: interleaved runs in worker processes, the summary, the base-path plot, and the
cluster option's error when Dask's scheduler is not installed."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.bench import run_planner_bench

SORTING = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "sorting_hsr.toml"


def test_bench_runs_seeds_in_worker_processes_and_plots_base_paths(tmp_path):
    png = tmp_path / "paths.png"
    out = run_planner_bench(SORTING, ["rlgp", "lgp"], seeds=1, workers=2, plot=png)
    assert [(r["seed"], r["planner"]) for r in out["runs"]] == [(0, "rlgp"), (0, "lgp")]  # interleaved
    for r in out["runs"]:
        assert r["success"], r["reason"]
        assert r["collision_free"] and r["goal_met"] and r["n_steps"] == 4
    assert out["summary"]["rlgp"]["success_rate"] == 1.0 and out["workers"] == 2
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_rejects_unknown_planners_and_bad_worker_counts():
    with pytest.raises(RlgpError, match="valid"):
        run_planner_bench(SORTING, ["rlgp", "magic"], seeds=1)
    with pytest.raises(RlgpError, match="at least 1"):
        run_planner_bench(SORTING, ["rlgp"], seeds=1, workers=0)


@pytest.mark.skipif(importlib.util.find_spec("distributed") is not None, reason="Dask's scheduler is installed")
def test_cluster_mode_without_dask_says_what_it_needs():
    with pytest.raises(RlgpError, match="dask"):
        run_planner_bench(SORTING, ["rlgp"], seeds=1, cluster="tcp://127.0.0.1:8786")


def test_a_run_that_crashes_natively_is_a_failed_run_not_the_end_of_the_sweep(monkeypatch):
    import os
    import signal

    from rlgp_exec.planning import bench

    monkeypatch.setattr(bench, "run_job", lambda *_: os.kill(os.getpid(), signal.SIGSEGV))  # in the child
    record, xy = bench.run_isolated(str(SORTING), "rlgp", 0)
    assert not record["success"] and xy == []
    assert record["reason"] == f"crashed: the planning process ended with exit code {-signal.SIGSEGV}"


def test_planner_memory_carries_the_graph_and_what_queries_taught_it_to_the_next_call():
    """The executive's replans start from what earlier plans learnt: the same graph object, with the
    nodes its queries inserted (a fresh load from the cache has fewer), and the second plan is valid."""
    from rlgp_exec.planning.memory import PlannerMemory
    from rlgp_exec.planning.registry import plan
    from rlgp_exec.reach import RGParams, load_or_build
    from rlgp_exec.scene import load_scene

    scene = load_scene(SORTING)
    memory = PlannerMemory()
    first = plan(scene, "rlgp", seed=0, memory=memory)
    assert first.success, first.reason
    (graph,) = memory.graphs.values()
    learnt = len(graph.alive)
    fresh, _ = load_or_build(scene, params=RGParams())
    assert learnt > len(fresh.alive)
    moved = scene.with_object_poses({"block_blue": (*scene.object("block_blue").pose[:1],
                                                    scene.object("block_blue").pose[1] + 0.03,
                                                    *scene.object("block_blue").pose[2:])})
    second = plan(moved, "rlgp", seed=1, memory=memory)
    assert second.success, second.reason
    assert memory.hits == 1 and list(memory.graphs.values()) == [graph] and len(graph.alive) >= learnt
