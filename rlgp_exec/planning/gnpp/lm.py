"""Levenberg-Marquardt on an NLP's row violations: GNPP's quick feasibility answers (``refute``'s random
starts, the top-grasp IK's screen of its later starts, ``gnpp_trn_lm``'s verdicts).

GNPP asks "is this subgraph feasible?" of hundreds of small NLPs per plan; IPOPT's "infeasible" verdicts,
which run to its iteration cap, were 60-67 % of its CPU (``tools/16_gnpp_nlp_corpus.py``). Here the
residual r(x) = g(x) - clip(g(x), lbg, ubg) (rows within their bounds drop out) is driven to zero by
damped Gauss-Newton steps, each projected onto the variable box: "feasible" once every row is within
``TOL``. It gives up when r.r falls by under 0.1 % for ``STALL`` steps after at least ``MIN_ITER``, or when
no damping finds a decrease (a stationary point of the violation, a local infeasibility certificate as
IPOPT's restoration phase ends in), or after ``max_iter`` steps.

The verdict is on the true bounds. A feasible point found so sits on the bounds it reached (a clearance
row at its margin: the upper arm at its distance to the table), which an interior-point solver's points
keep off; ``polish`` then moves it inside the inequality rows (``INSETS``: 1 cm, else less) where a few
steps can, without giving up the verdict. (The verdict itself is not aimed inside them: Hanoi's discs
only just fit on their pegs.) ``sparse`` steps serve a whole plan's graph
(``GraphSolver.polish``).
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np
import scipy.sparse as sp
from scipy.sparse.linalg import spsolve

from rlgp_exec.casadi_call import BufferedFunction
from rlgp_exec.robot.model import FloatArray

__all__ = ["BACKOFF", "INSETS", "TOL", "LevenbergMarquardt"]

Symbolic = Any  # ca.MX or ca.SX (both work; CasADi's stubs take one kind per call)

TOL = 1e-6  # [m or rad] every row within this of its bounds: feasible
BACKOFF = 0.01  # [m or rad] how far ``polish`` tries first to move a point inside the inequality rows
#: [m or rad] the insets ``polish`` tries in turn: on obstacles_tower_pr2 seed 1 a hand at a place had no
#: room for 1 cm from an obstacle, and 3.3 mm was enough for the replay
INSETS = (BACKOFF, BACKOFF / 3, BACKOFF / 10)
MIN_ITER = 15
STALL = 5
POLISH_ITER = 10
LAMBDA_MAX = 1e8


class LevenbergMarquardt:
    """The feasibility problem ``lbg <= g(x, p) <= ubg, lbx <= x <= ubx`` of the NLP ``{"x", "p", "g"}``
    (MX or SX expressions; any objective is not used: the answer is a point, feasible or the least violating
    found). Called like an nlpsol (x0, p, lbx, ubx, lbg, ubg -> {"x": ...}, then ``stats()``).
    ``sparse``: sparse steps (a whole plan's graph; dense ones are faster on small NLPs)."""

    def __init__(self, x: Symbolic, p: Symbolic, g: Symbolic, max_iter: int, sparse: bool = False) -> None:
        jac = ca.jacobian(g, x)
        self._gj = ca.Function("g_jac", [x, p], [g, jac if sparse else ca.densify(jac)])
        self.sparse = sparse
        self.max_iter = max_iter
        self._iterations = 0
        self._call = BufferedFunction(self._gj)  # DM conversions were most of LM's time
        sp_jac = self._gj.sparsity_out(1)
        self._jac_idx = (np.asarray(sp_jac.row()), np.asarray(sp_jac.colind()), (g.numel(), x.numel()))

    @classmethod
    def of_oracle(cls, oracle: ca.Function, max_iter: int) -> LevenbergMarquardt:
        """For an NLP given as its oracle (x, p) -> (f, g) (``nlpsol(...).oracle()``, a recorded corpus)."""
        x, p = ca.MX.sym("x", oracle.size1_in(0)), ca.MX.sym("p", oracle.size1_in(1))
        return cls(x, p, oracle(x, p)[1], max_iter)

    def __call__(
        self, *, x0: FloatArray, p: FloatArray, lbx: FloatArray, ubx: FloatArray, lbg: FloatArray, ubg: FloatArray
    ) -> dict[str, FloatArray]:
        x = np.clip(np.asarray(x0, float), lbx, ubx)
        lbg, ubg = np.asarray(lbg, float), np.asarray(ubg, float)
        x, self._iterations = self._descend(x, p, lbx, ubx, lbg, ubg, self.max_iter)
        return {"x": x}

    def violation(self, x: FloatArray, p: FloatArray, lbg: FloatArray, ubg: FloatArray) -> float:
        """The largest distance of a row of g(x, p) outside [lbg, ubg] (``TOL`` or less: feasible)."""
        r, _ = self._residual(np.asarray(x, float), p, np.asarray(lbg, float), np.asarray(ubg, float))
        return float(np.max(np.abs(r), initial=0.0))

    def stats(self) -> dict:
        return {"iter_count": self._iterations, "return_status": "levenberg-marquardt"}

    def polish(
        self, x: FloatArray, p: FloatArray, lbx: FloatArray, ubx: FloatArray, lbg: FloatArray, ubg: FloatArray
    ) -> FloatArray:
        """The feasible point ``x`` moved inside every inequality row by the first of ``INSETS`` (a quarter
        of a narrower row's width at most) that ``POLISH_ITER`` steps reach (every row then within ``TOL``
        of its inset bounds, the equality rows of their values); else ``x`` itself."""
        x = np.asarray(x, float)
        lbg, ubg = np.asarray(lbg, float), np.asarray(ubg, float)
        lo_fin, hi_fin = np.isfinite(lbg), np.isfinite(ubg)
        for inset in INSETS:
            d = np.minimum(inset, 0.25 * (ubg - lbg))  # 0 on equality rows
            lo, hi = lbg.copy(), ubg.copy()
            lo[lo_fin] += d[lo_fin]
            hi[hi_fin] -= d[hi_fin]
            moved, _ = self._descend(x, p, lbx, ubx, lo, hi, POLISH_ITER, patient=False)
            r, _ = self._residual(moved, p, lo, hi)
            if float(np.max(np.abs(r), initial=0.0)) <= TOL:
                return moved
        return x

    def _residual(self, x: FloatArray, p: FloatArray, lbg: FloatArray, ubg: FloatArray):
        """(r (m,), its Jacobian (m, n): an array, or a CSR matrix if ``sparse``)."""
        g, nz = self._call(x, p)
        row, colind, shape = self._jac_idx
        jac = sp.csc_matrix((nz, row, colind), shape=shape).tocsr() if self.sparse else self._call.dense(1, nz)
        return g - np.clip(g, lbg, ubg), jac

    def _solve(self, h, grad: FloatArray, lam: float) -> FloatArray:
        """The damped Gauss-Newton step's solution of (h + lam (diag(h) + 1e-9)) dx = grad."""
        if self.sparse:
            d = h.diagonal() + 1e-9
            return np.asarray(spsolve(sp.csc_matrix(h + sp.diags(lam * d)), grad)).reshape(-1)
        return np.linalg.solve(h + lam * (np.diag(np.diag(h)) + 1e-9 * np.eye(h.shape[0])), grad)

    def _descend(
        self,
        x: FloatArray,
        p: FloatArray,
        lbx: FloatArray,
        ubx: FloatArray,
        lbg: FloatArray,
        ubg: FloatArray,
        max_iter: int,
        patient: bool = True,
    ) -> tuple[FloatArray, int]:
        """(the point reached from ``x``, the steps taken); ``patient``: the stall rule waits ``MIN_ITER``
        steps."""
        r, jac = self._residual(x, p, lbg, ubg)
        f, lam, stall, it = float(r @ r), 1e-3, 0, 0
        for it in range(1, max_iter + 1):
            if float(np.max(np.abs(r), initial=0.0)) <= TOL:
                return x, it - 1
            off = r != 0.0
            ja, ra = jac[off], r[off]
            h, grad = ja.T @ ja, ja.T @ ra
            while True:
                xn = np.clip(x - self._solve(h, grad, lam), lbx, ubx)
                rn, jn = self._residual(xn, p, lbg, ubg)
                fn = float(rn @ rn)
                if fn < f:
                    lam = max(lam / 3.0, 1e-9)
                    break
                lam *= 4.0
                if lam > LAMBDA_MAX:  # no step decreases the violation: a stationary point
                    return x, it
            stall = stall + 1 if f - fn < 1e-3 * f else 0
            x, r, jac, f = xn, rn, jn, fn
            if stall >= STALL and (it >= MIN_ITER or not patient):
                break
        return x, it
