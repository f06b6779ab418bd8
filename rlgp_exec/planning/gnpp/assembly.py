"""A (sub)graph-NLP's rows as one CasADi expression, with their Jacobian assembled from the factors'.

``assemble`` calls each factor's cached function (``FactorLib.factor``) on the NLP variables that its
variables became after ``presolve`` (or on their constants), stacks the rows, and gives the stacked rows of
the kept factors a Jacobian put together from the factors' own, each built once per factor key
(``FactorFn.jac``): ``diagcat(J_1, ..., J_m) @ S``, where the constant 0/1 matrix S takes each factor's
input slots to the NLP's variables (a constant slot to nothing; two slots on one variable add up). The
rows are wrapped in a function of x whose ``custom_jacobian`` is that product, so IPOPT's
``nlp_jac_g`` (and Levenberg-Marquardt's Jacobian) come from it instead of CasADi differentiating the
whole MX graph again for every new subgraph structure (~4 ms each). The same Jacobian (to rounding): a
test checks it against CasADi's AD of the plain rows at random points.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.pntc import Factor, Var
from rlgp_exec.planning.gnpp.presolve import Presolved
from rlgp_exec.robot.model import FloatArray

__all__ = ["Assembled", "assemble"]


@dataclass(frozen=True)
class Assembled:
    """The NLP variable ``x`` (the free variables of ``Presolved`` stacked, (n,)) and its rows.

    ``g_all``: every input factor's rows, in input order (a plain expression: for the violations);
    ``rows[k]``: factor k's row range in it, ``lo_all``/``hi_all`` their bounds; ``g``: the kept factors'
    rows (``Presolved.kept``), with the assembled Jacobian, ``lbg``/``ubg`` theirs; ``g_plain``: the same
    rows without it (tests compare the two Jacobians)."""

    x: ca.MX
    g_all: ca.MX
    rows: tuple[tuple[int, int], ...]
    lo_all: FloatArray
    hi_all: FloatArray
    g: ca.MX
    g_plain: ca.MX
    lbg: FloatArray
    ubg: FloatArray


def assemble(lib: FactorLib, factors: Sequence[Factor], order: Sequence[Var], pre: Presolved) -> Assembled:
    """The rows of ``factors`` over the variables ``order`` reduced by ``pre`` (``presolve``'s)."""
    dims = [lib.dim(order[i].kind, order[i].owner) for i in pre.free]
    offs = np.cumsum([0, *dims]).astype(int)
    x = ca.MX.sym("x", int(offs[-1]))
    slot: dict[Var, ca.MX | ca.DM] = {}
    first: dict[Var, int] = {}  # a free variable's first column in x
    for i, v in enumerate(order):
        kind, where = pre.slot_of(i)
        if kind == "const":
            slot[v] = ca.DM(where)
        else:
            assert isinstance(where, int)
            slot[v] = x[int(offs[where]) : int(offs[where + 1])]
            first[v] = int(offs[where])
    gs, lo, hi, rows = [], [], [], []
    n = 0
    for f in factors:
        ff = lib.factor(f.key)
        gs.append(ff.fn(*[slot[v] for v in f.vars]))
        lo.append(ff.lower)
        hi.append(ff.upper)
        rows.append((n, n + len(ff.lower)))
        n += len(ff.lower)
    g_plain = ca.vertcat(*[gs[k] for k in pre.kept])
    lbg = np.concatenate([lo[k] for k in pre.kept]) if pre.kept else np.zeros(0)
    ubg = np.concatenate([hi[k] for k in pre.kept]) if pre.kept else np.zeros(0)
    g = _with_jacobian(x, g_plain, _jacobian(lib, factors, pre.kept, slot, first, x.numel())) if pre.kept else g_plain
    lo_all = np.concatenate(lo) if lo else np.zeros(0)
    hi_all = np.concatenate(hi) if hi else np.zeros(0)
    return Assembled(x, ca.vertcat(*gs), tuple(rows), lo_all, hi_all, g, g_plain, lbg, ubg)


def _jacobian(
    lib: FactorLib,
    factors: Sequence[Factor],
    kept: Sequence[int],
    slot: dict[Var, ca.MX | ca.DM],
    first: dict[Var, int],
    n: int,
) -> ca.MX:
    """d(kept rows)/dx, (rows, n): the factors' Jacobians in their input slots, block-diagonal, times the
    0/1 matrix that takes input slots to columns of x."""
    blocks: list[ca.MX] = []
    slot_rows: list[int] = []  # stacked input slots that are columns of x, and those columns
    cols: list[int] = []
    at = 0  # the first stacked input slot of the factor
    for k in kept:
        f = factors[k]
        ff = lib.factor(f.key)
        blocks.append(ff.jac(*[slot[v] for v in f.vars]))
        for v in f.vars:
            d = lib.dim(v.kind, v.owner)
            if v in first:
                slot_rows.extend(range(at, at + d))
                cols.extend(range(first[v], first[v] + d))
            at += d
    scatter = ca.DM(ca.Sparsity.triplet(at, n, slot_rows, cols), 1.0)
    return ca.mtimes(ca.diagcat(*blocks), scatter)


def _with_jacobian(x: ca.MX, g: ca.MX, jac: ca.MX) -> ca.MX:
    """``g`` as a call of a function of ``x`` whose Jacobian is ``jac`` (CasADi's ``custom_jacobian``,
    signature (x, out_g) -> jac_g_x; ``jac_penalty`` 0: derivatives of the call always go through it)."""
    jac_fn = ca.Function("jac_rows", [x, ca.MX.sym("out_g", g.sparsity())], [jac], ["x", "out_g"], ["jac_g_x"])
    rows = ca.Function(
        "rows", [x], [g], ["x"], ["g"], {"never_inline": True, "custom_jacobian": jac_fn, "jac_penalty": 0}
    )
    return rows(x)
