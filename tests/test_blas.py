"""Planning runs one BLAS thread: IPOPT's (the OpenBLAS bundled with CasADi, under MUMPS) and numpy's,
scipy's and OpenCV's copies."""

from __future__ import annotations

from pathlib import Path

import casadi as ca
import cv2  # noqa: F401  (its OpenBLAS copy loaded, as in the executive)
import numpy as np
import scipy.linalg  # noqa: F401

from rlgp_exec.planning.blas import CASADI_OPENBLAS, blas_threads, single_blas_thread


def _mapped(stem: str) -> set[str]:
    """The files mapped into this process whose path contains ``stem`` (Linux, as the project)."""
    return {line.split()[-1] for line in Path("/proc/self/maps").read_text().splitlines() if stem in line}


def test_every_blas_copy_runs_one_thread_and_ipopt_uses_the_copy_that_was_set() -> None:
    single_blas_thread()
    threads = blas_threads()
    assert CASADI_OPENBLAS in threads
    assert any("numpy" in path for path in threads)
    assert set(threads.values()) == {1}, threads
    x = ca.SX.sym("x", 3)
    solver = ca.nlpsol("blas_check", "ipopt", {"x": x, "f": ca.sumsqr(x - 1), "g": x[0] + x[1]},
                       {"ipopt.print_level": 0, "print_time": False, "ipopt.sb": "yes"})
    res = solver(x0=[0, 0, 0], lbg=0.5, ubg=0.5)
    assert np.allclose(np.asarray(res["x"]).ravel(), [0.25, 0.25, 1.0], atol=1e-6)
    # IPOPT's MUMPS linked that same copy (one file of it mapped), still at one thread
    assert len(_mapped(CASADI_OPENBLAS.split(".so")[0])) == 1
    assert blas_threads()[CASADI_OPENBLAS] == 1
