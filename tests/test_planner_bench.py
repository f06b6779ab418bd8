"""The planner bench: interleaved runs in worker processes, the summary, the base-path plot, and the
cluster option: a sweep on a local Dask cluster, and its errors."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from rlgp_exec.bench.planners import run_planner_bench
from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.sequence import STAGES

SORTING = Path(__file__).resolve().parents[1] / "sim" / "scenes" / "sorting_hsr.toml"


def test_bench_runs_seeds_in_worker_processes_and_plots_base_paths(tmp_path):
    png = tmp_path / "paths.png"
    out = run_planner_bench(SORTING, ["rlgp", "lgp"], seeds=1, workers=2, plot=png)
    assert [(r["seed"], r["planner"]) for r in out["runs"]] == [(0, "rlgp"), (0, "lgp")]  # interleaved
    for r in out["runs"]:
        assert r["success"], r["reason"]
        assert r["collision_free"] and r["goal_met"] and r["n_steps"] == 4
    assert out["summary"]["rlgp"]["success_rate"] == 1.0 and out["workers"] == 2
    for r in out["runs"]:  # where the time went: every stage of the geometric layer, within the whole
        assert list(r["stages_s"]) == list(STAGES) and min(r["stages_s"].values()) > 0.0
        assert sum(r["stages_s"].values()) < r["planning_time_s"]
    stages = out["summary"]["rlgp"]["stages_s_median"]
    assert list(stages) == [*STAGES, "other"] and stages["other"] > 0.0
    assert png.stat().st_size > 10_000 and png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_rejects_unknown_planners_and_bad_worker_counts():
    with pytest.raises(RlgpError, match="valid"):
        run_planner_bench(SORTING, ["rlgp", "magic"], seeds=1)
    with pytest.raises(RlgpError, match="at least 1"):
        run_planner_bench(SORTING, ["rlgp"], seeds=1, workers=0)


def test_the_sweep_runs_on_a_dask_cluster_given_its_address():
    """`bench --cluster ADDRESS`: the jobs run on the cluster's workers (a local cluster with one worker
    process here), the plans are validated there, and the summary is the same kind as a local sweep."""
    from dask.distributed import Client, LocalCluster

    with LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
        out = run_planner_bench(SORTING, ["rlgp"], seeds=1, cluster=cluster.scheduler_address)
        with Client(cluster.scheduler_address) as client:
            ran = client.run_on_scheduler(lambda dask_scheduler: sorted(dask_scheduler.task_prefixes))
    assert "run_job" in ran  # executed by the cluster, not locally
    (run,) = out["runs"]
    assert run["success"] and run["collision_free"] and run["goal_met"], run["reason"]
    assert out["cluster"] == cluster.scheduler_address and out["summary"]["rlgp"]["success_rate"] == 1.0


def test_cluster_mode_says_what_it_needs(monkeypatch):
    with pytest.raises(RlgpError, match="no Dask scheduler answered"):
        run_planner_bench(SORTING, ["rlgp"], seeds=1, cluster="tcp://127.0.0.1:9")
    monkeypatch.setitem(sys.modules, "dask.distributed", None)  # as without Dask installed
    with pytest.raises(RlgpError, match="dask"):
        run_planner_bench(SORTING, ["rlgp"], seeds=1, cluster="tcp://127.0.0.1:8786")


def test_a_job_that_raises_is_a_failed_run_with_the_reason():
    """A job whose future raises (on a cluster: a worker killed natively on it, thrice) is recorded."""
    from concurrent.futures import ThreadPoolExecutor

    from rlgp_exec.bench.planners import _submit_all

    def boom(scene_path, planner, seed, limits):
        raise RuntimeError(f"{planner} {seed} lost")

    with ThreadPoolExecutor(1) as ex:
        ((rec, xy),) = _submit_all([(3, "rlgp")], ex.submit, str(SORTING), job=boom)
    assert not rec["success"] and rec["seed"] == 3 and rec["reason"] == "lost: RuntimeError: rlgp 3 lost" and xy == []


def test_a_run_that_crashes_natively_is_a_failed_run_not_the_end_of_the_sweep(monkeypatch):
    import os
    import signal

    from rlgp_exec.bench import planners as bench

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
