"""One BLAS thread for planning. A planning process holds four OpenBLAS copies, each running a thread per
core by default: CasADi's (``libcasadi-tp-openblas``, under IPOPT's MUMPS), numpy's, scipy's and
OpenCV's. On our problems (KKT systems of a few hundred rows, small arrays) the second thread buys no
wall time and costs CPU on the core the robot's HAL and perception need: a level-3 path NLP of
pick_place_pr2 took 0.16-0.23 s of wall time with one thread or two, but 0.35-0.40 s of CPU with two
(half of it system time in the threads' hand-offs).

``single_blas_thread()`` sets them all to one thread: CasADi's through its own setter (loaded first if
IPOPT has not yet: the dynamic linker then gives IPOPT that same copy; threadpoolctl does not know its
file name), the others through threadpoolctl. A library that is not there is left alone.
"""

from __future__ import annotations

import ctypes
import logging
from pathlib import Path

from threadpoolctl import threadpool_info, threadpool_limits

__all__ = ["CASADI_OPENBLAS", "blas_threads", "single_blas_thread"]

log = logging.getLogger(__name__)
CASADI_OPENBLAS = "libcasadi-tp-openblas.so.0"  # in the casadi package's folder
_casadi: ctypes.CDLL | None = None
_tried = False


def _casadi_openblas() -> ctypes.CDLL | None:
    global _casadi, _tried
    if not _tried:
        _tried = True
        # local: probed once, on the first solve: a process that never solves loads no CasADi
        import casadi

        path = Path(casadi.__file__).parent / CASADI_OPENBLAS
        try:
            lib = ctypes.CDLL(str(path))
            lib.openblas_set_num_threads.argtypes = [ctypes.c_int]
            _casadi = lib
        except (OSError, AttributeError) as e:
            log.debug("no OpenBLAS of CasADi's to set (%s): it keeps its thread count", e)
    return _casadi


def single_blas_thread() -> None:
    """Every BLAS copy loaded (and CasADi's) to one thread; idempotent."""
    lib = _casadi_openblas()
    if lib is not None and lib.openblas_get_num_threads() != 1:
        lib.openblas_set_num_threads(1)
    if any(pool["num_threads"] != 1 for pool in threadpool_info() if pool["user_api"] == "blas"):
        threadpool_limits(limits=1, user_api="blas")


def blas_threads() -> dict[str, int]:
    """Thread count per BLAS library loaded, by file path (CasADi's under its name)."""
    out = {pool["filepath"]: int(pool["num_threads"]) for pool in threadpool_info() if pool["user_api"] == "blas"}
    lib = _casadi_openblas()
    if lib is not None:
        out[CASADI_OPENBLAS] = int(lib.openblas_get_num_threads())
    return out
