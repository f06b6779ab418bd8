"""``casadi_call.BufferedFunction``: the values of the ordinary (DM) call, at every call."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from rlgp_exec.casadi_call import BufferedFunction


def test_outputs_equal_the_dm_call_at_every_point_dense_and_sparse():
    x, M = ca.SX.sym("x", 4), ca.SX.sym("M", 2, 3)
    g = ca.vertcat(ca.sin(x[0]) * x[1], x[2] ** 2 + M[1, 2], ca.SX(1, 1), x[3] * M[0, 0])  # a structural zero
    fn = ca.Function("f", [x, M], [g, ca.jacobian(g, x), ca.densify(ca.jacobian(g, x)), M.T @ x[:2]])
    assert not fn.sparsity_out(0).is_dense() and not fn.sparsity_out(1).is_dense()
    call = BufferedFunction(fn)
    rng = np.random.default_rng(0)
    for _ in range(5):  # rebinding nothing: each call reads its new inputs
        xv, Mv = rng.normal(size=4), rng.normal(size=(2, 3))
        got = call(xv, Mv)
        want = fn(xv, Mv)
        for k, w in enumerate(want):
            assert np.array_equal(call.dense(k, got[k]), np.asarray(ca.densify(w)))
    first = call(np.ones(4), np.ones((2, 3)))[0]
    call(np.zeros(4), np.zeros((2, 3)))
    assert np.array_equal(first, call(np.ones(4), np.ones((2, 3)))[0])  # results are copies


def test_a_sparse_input_is_refused_with_its_name():
    y = ca.SX.sym("y", ca.Sparsity.diag(3))
    with pytest.raises(ValueError, match="sparse_in: input 0 is sparse"):
        BufferedFunction(ca.Function("sparse_in", [y], [ca.sum1(ca.sum2(y))]))
