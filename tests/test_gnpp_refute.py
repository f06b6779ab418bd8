"""``refute`` on a mobile arm: the check of a conflict before GNPP learns it.

HSR sorting, 4 blocks, seed 0: picking ``block_blue_1`` from its start (Ref, Kin, Grasp, ColFix; the base
free) is feasible, yet from the guess the search reached in one plan (the base at y = -0.48 m, the hand
at the tilt bound, the fingers off the block's faces) every start ``refute`` had kept that base, and for
some seeds none reached a feasible point: the conflict was learnt, and with it every sorting plan was
forbidden ("infeasible")."""

from __future__ import annotations

import numpy as np
import pytest

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.graph import canonical
from rlgp_exec.planning.gnpp.guess import TopIK, ik_seed
from rlgp_exec.planning.gnpp.pntc import Factor, Var
from rlgp_exec.planning.gnpp.solver import GraphSolver
from rlgp_exec.planning.symbolic.reformulate import PartialState
from rlgp_exec.robot import load_robot
from rlgp_exec.scene.generate import sorting_scene

OBJ = "block_blue_1"
#: the guess of the learnt conflict's variables (the arm's [x, y, yaw, joints], the held pose) [m, rad]
Q_GUESS = np.array([-0.17884, -0.48500, 1.16769, 0.17482, -1.03106, -0.41199, -1.30236, 0.45395])
R_GUESS = np.array([0.015, 0.0, np.pi, -0.83645])


def _pick(t: int) -> list[Factor]:
    """The pick of ``OBJ`` from its start pose at step t -> t + 1, the base free."""
    q, w, r = Var("q", "arm", t + 1), Var("x", OBJ, t), Var("x", OBJ, t + 1)
    none = ((t, PartialState(frozenset(), frozenset())),)
    return [
        Factor(("Ref", OBJ), (w,), none),
        Factor(("Kin", OBJ, "arm"), (q, w, r), none),
        Factor(("Grasp", OBJ), (r,), none),
        Factor(("ColFix", "arm"), (q,), none),
    ]


@pytest.fixture(scope="module")
def hsr4():
    lib = FactorLib(load_robot("hsr"), sorting_scene("hsr", 4, 0), None)
    return lib, TopIK(lib)


def _solver(lib: FactorLib, ik: TopIK) -> GraphSolver:
    solver = GraphSolver(lib)
    solver.seeder = lambda factors, guess, bearing=0: ik_seed(lib, ik, factors, guess, bearing)
    return solver


def _guess(lib: FactorLib, t: int) -> dict[Var, np.ndarray]:
    return {Var("q", "arm", t + 1): Q_GUESS.copy(), Var("x", OBJ, t): lib.start_pose(OBJ),
            Var("x", OBJ, t + 1): R_GUESS.copy()}


@pytest.mark.parametrize("seed", [0, 1, 2, 4])
def test_picking_a_block_from_its_start_is_refuted_from_the_guess_of_the_learnt_conflict(hsr4, seed):
    """Every seed refutes it: the seeder's IK also starts with the base on other bearings round the block
    (before, seeds 1 and 2 of these found no feasible point, and the conflict was learnt)."""
    lib, ik = hsr4
    factors = _pick(14)
    point = _solver(lib, ik).refute(factors, _guess(lib, 14), seed=seed)
    assert point is not None
    check = GraphSolver(lib).solve(factors, point)  # a solve of its own confirms the point
    assert check.feasible and max(check.violations) < 1e-4


def test_a_problem_refuted_once_is_refuted_again_from_its_point(hsr4):
    """The same pick in a later plan (other time steps, a guess from which no start is tried: ``tries=0``)
    is refuted by one solve, from the point found the first time, mapped by ``graph.canonical``."""
    lib, ik = hsr4
    solver = _solver(lib, ik)
    assert solver.refute(_pick(10), _guess(lib, 10), seed=0) is not None
    assert canonical(_pick(10))[0] == canonical(_pick(20))[0]
    n = solver.n_solves
    point = solver.refute(_pick(20), _guess(lib, 20), tries=0)
    assert point is not None and solver.n_solves == n + 1
    assert GraphSolver(lib).solve(_pick(20), point).feasible
