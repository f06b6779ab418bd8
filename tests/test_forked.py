"""``planning.forked.fork_map``: the plain loop's answer, whatever the child does."""

from __future__ import annotations

import os
import time

import numpy as np
import pytest

from rlgp_exec.planning import forked

PARENT = os.getpid()


def _work(k: int) -> forked.Result:
    rng = np.random.default_rng(k)
    return {"k": k, "name": f"item {k}", "ok": k % 3 == 0, "none": None, "x": float(rng.normal()),
            "Z": rng.normal(size=(k + 1, 3)), "idx": np.arange(k, dtype=np.int64)}


def _same(a: list[forked.Result], b: list[forked.Result]) -> bool:
    if len(a) != len(b):
        return False
    for ra, rb in zip(a, b, strict=True):
        if ra.keys() != rb.keys():
            return False
        for key in ra:
            va, vb = ra[key], rb[key]
            if isinstance(va, np.ndarray):
                if not (isinstance(vb, np.ndarray) and va.dtype == vb.dtype and np.array_equal(va, vb)):
                    return False
            elif va != vb or type(va) is not type(vb):
                return False
    return True


@pytest.mark.parametrize("n", [0, 1, 2, 5, 6])
def test_fork_map_returns_the_loops_results_in_order(n):
    items = list(range(n))
    assert _same(forked.fork_map(_work, items), [_work(k) for k in items])
    assert _same(forked.fork_map(_work, items, workers=1), [_work(k) for k in items])


def test_a_child_that_fails_leaves_its_items_to_the_parent(caplog):
    def fails_in_the_child(k: int) -> forked.Result:
        if os.getpid() != PARENT:
            raise RuntimeError("the child breaks")
        return _work(k)

    assert _same(forked.fork_map(fails_in_the_child, list(range(5))), [_work(k) for k in range(5)])
    assert "the child failed" in caplog.text


def test_a_child_that_hangs_is_killed_and_its_items_done_here(monkeypatch, caplog):
    monkeypatch.setattr(forked, "MIN_TIMEOUT_S", 0.5)

    def hangs_in_the_child(k: int) -> forked.Result:
        if os.getpid() != PARENT:
            time.sleep(60.0)
        return _work(k)

    t0 = time.perf_counter()
    assert _same(forked.fork_map(hangs_in_the_child, list(range(4))), [_work(k) for k in range(4)])
    assert time.perf_counter() - t0 < 10.0
    assert "did not answer in time" in caplog.text


def test_an_error_in_the_parent_propagates_and_the_child_is_reaped():
    def fails_here(k: int) -> forked.Result:
        if os.getpid() == PARENT:
            raise ValueError("bad item")
        return _work(k)

    with pytest.raises(ValueError, match="bad item"):
        forked.fork_map(fails_here, [0, 1, 2])
    with pytest.raises(ChildProcessError):
        os.waitpid(-1, os.WNOHANG)  # no child left behind


def test_frames_round_trip_and_bad_ones_are_refused():
    results = [_work(k) for k in range(3)]
    frame = forked.encode(results)
    assert _same(forked.decode(frame), results)
    with pytest.raises(ValueError, match="shorter"):
        forked.decode(frame[:4])
    with pytest.raises(ValueError, match="header"):
        forked.decode(frame[:8] + b"{not json" + frame[17:])
    with pytest.raises(ValueError, match="past the frame"):
        forked.decode(frame[:-8])
    with pytest.raises(TypeError, match="valid"):
        forked.encode([{"bad": [1, 2]}])  # type: ignore[dict-item]
