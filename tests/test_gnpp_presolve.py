"""GNPP's presolve: pinned and copied variables leave the NLP, and the verdicts and solutions stay
those of the input graph (every input factor is satisfied at a "feasible" point)."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.planning.gnpp.geometry import LIFT, FactorLib
from rlgp_exec.planning.gnpp.graph import Relaxation, relax, variables
from rlgp_exec.planning.gnpp.guess import TopIK, initial_guess
from rlgp_exec.planning.gnpp.pntc import Factor, add_flags, factors_of
from rlgp_exec.planning.gnpp.presolve import PINNING, presolve
from rlgp_exec.planning.gnpp.solver import FEAS_TOL, GraphSolver
from rlgp_exec.planning.symbolic import GroundAction, ground_scene
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene
from rlgp_exec.scene.literals import parse_literal

SCENES = Path(__file__).resolve().parents[1] / "sim" / "scenes"
PLAN = (
    "(pick right_arm b2 table)",
    "(place right_arm b2 table)",
    "(pick left_arm b1 table)",
    "(place left_arm b1 goal_region)",
    "(pick right_arm b2 table)",
    "(stack right_arm b2 b1)",
)


@pytest.fixture(scope="module")
def setup():
    sc = load_scene(SCENES / "tower_pr2.toml")
    keep = ["b1", "b2", "b3"]
    goal = ("(on b1 goal_region)", "(on b2 b1)")
    scene = dataclasses.replace(
        sc,
        objects=tuple(o for o in sc.objects if o.name in keep),
        goal=dataclasses.replace(sc.goal, literals=tuple(parse_literal(g) for g in goal)),
    )
    lib = FactorLib(load_robot("pr2"), scene)
    task = add_flags(ground_scene(scene, manipulators=list(lib.arms)))
    states = task.simulate([GroundAction.parse(a) for a in PLAN])
    graph = factors_of(states, lib.arms, keep)
    guess = initial_guess(lib, TopIK(lib), states, variables(graph))
    return lib, graph, guess


def test_pinned_and_copied_variables_leave_the_nlp(setup):
    lib, graph, _ = setup
    order = variables(graph)
    pre = presolve(lib, graph, order)
    pos = {v: i for i, v in enumerate(order)}
    for f in graph:
        if f.kind == "Equal":  # copies share one NLP variable
            a, b = (pos[v] for v in f.vars)
            assert pre.rep[a] == pre.rep[b]
        if f.kind in ("Ref", "RefQ"):  # pinned to the scene pose / the start configuration
            kind, value = pre.slot_of(pos[f.vars[0]])
            want = lib.start_pose(f.key[1]) if f.kind == "Ref" else lib.home_q(f.key[1])
            assert kind == "const" and np.allclose(value, want)
    kept = [graph[k] for k in pre.kept]
    assert not any(f.kind in PINNING for f in kept)
    sigs = [(f.key, tuple(pre.rep[pos[v]] for v in f.vars)) for f in kept]
    assert len(sigs) == len(set(sigs))  # no factor repeated after the merge
    assert all(any(r not in pre.const for r in sig[1]) for sig in sigs)  # each keeps a free variable
    assert len(pre.free) < len(order) and len(pre.kept) < len(graph)


@pytest.mark.parametrize("rel", [Relaxation.NO_COL, Relaxation.NONE])
def test_a_feasible_point_satisfies_every_input_factor(setup, rel):
    lib, graph, guess = setup
    sub = relax(graph, rel)
    res = GraphSolver(lib).solve(sub, guess)
    assert res.feasible
    assert len(res.violations) == len(sub) and max(res.violations) <= FEAS_TOL
    for f in sub:  # checked independently of the solver, factor by factor
        ff = lib.factor(f.key)
        g = np.asarray(ff.fn(*[res.values[v] for v in f.vars])).reshape(-1)
        assert np.all(g >= ff.lower - FEAS_TOL) and np.all(g <= ff.upper + FEAS_TOL), str(f)


def test_a_contradictory_pin_stays_infeasible(setup):
    """b1's scene pose (pinned by Ref) asked to lie on the goal region: the constant violates the
    placement, and the violation is reported against that factor, not the pin."""
    lib, graph, guess = setup
    place = next(f for f in graph if f.kind == "Place" and f.key[1:] == ("b1", "goal_region"))
    ref = next(f for f in graph if f.kind == "Ref" and f.key[1] == "b1")
    moved = Factor(place.key, ref.vars, place.partial)
    ff = lib.factor(place.key)
    g = np.asarray(ff.fn(lib.start_pose("b1"))).reshape(-1)
    assert np.any(g < ff.lower - FEAS_TOL) or np.any(g > ff.upper + FEAS_TOL)  # b1 starts off the region
    solver = GraphSolver(lib)
    res = solver.solve([ref, moved], guess)
    assert not res.feasible
    assert res.violations[0] == 0.0 and res.violations[1] > FEAS_TOL
    assert solver.iters == []  # no free variable: nothing for IPOPT to do


def test_hand_rows_cover_the_vertical_line_above_the_keyframe(setup):
    """ColHO keeps each hand sphere's vertical line of LIFT clear (the descent onto the keyframe and the
    lift off it): a box above a fingertip within LIFT is a violation, one below it or beside it is not."""
    lib, _, _ = setup
    arm = "right_arm"
    q = lib.home_q(arm)
    sh = lib.arm_shapes(arm)
    P = np.asarray(sh.fn(q)[0])
    tip, r = P[:, sh.hand[1]], sh.radii[sh.hand[1]]
    ff = lib.factor(("ColHO", arm, "b1"))
    half = lib.objects["b1"].size[2] / 2

    def clear(dx: float, dz: float) -> bool:
        w = np.array([tip[0] + dx, tip[1], tip[2] + dz, 0.0])
        g = np.asarray(ff.fn(q, w)).reshape(-1)
        return bool(np.all(g >= ff.lower - 1e-9))

    assert not clear(0.0, LIFT / 2 + half)  # the box's bottom halfway up the line
    assert not clear(0.0, LIFT + half + r / 2)  # just above the top of the line, within the radius
    top = max(P[2, k] + sh.radii[k] for k in sh.hand) + LIFT  # the highest point of every swept sphere
    bottom = min(P[2, k] - sh.radii[k] for k in sh.hand)
    assert clear(0.0, top - tip[2] + half + 0.01)  # above every line
    assert clear(0.0, bottom - tip[2] - half - 0.01)  # below the hand: the lines go up only
    assert clear(0.3, LIFT / 2)  # beside it


def test_an_object_only_nlp_gets_more_starts_only_when_infeasible(setup):
    """Over object poses only, an "infeasible" verdict from the guess is checked from OBJECT_STARTS
    perturbed starts too (cheap NLPs; a block started inside its neighbour misleads the solver); a
    feasible one stops at the first start. A contradiction stays infeasible."""
    from rlgp_exec.planning.gnpp.pntc import Var
    from rlgp_exec.planning.gnpp.solver import OBJECT_STARTS

    lib, graph, _ = setup
    xb1, xb2 = Var("x", "b1", 99), Var("x", "b2", 99)
    ps = next(f for f in graph if f.kind == "Place").partial
    ref = Factor(("Ref", "b2"), (xb2,), ps)
    on = Factor(("On", "b1", "b2"), (xb1, xb2), ps)
    place = Factor(("Place", "b1", "goal_region"), (xb1,), ps)
    apart = Factor(("ColOO", "b1", "b2"), (xb1, xb2), ps)
    start = {xb1: lib.start_pose("b2"), xb2: lib.start_pose("b2")}  # b1 started inside b2
    solver = GraphSolver(lib)
    res = solver.solve([ref, place, apart], start)
    assert res.feasible and max(res.violations) <= FEAS_TOL
    n = len(solver.iters)
    assert not solver.solve([ref, on, place], start).feasible  # on b2 (off the region) and on the region
    assert len(solver.iters) - n == 1 + OBJECT_STARTS
    n = len(solver.iters)
    assert solver.solve([ref, on], start).feasible
    assert len(solver.iters) - n == 1


@pytest.mark.parametrize("rel", [Relaxation.NO_ROBOT | Relaxation.NO_COL, Relaxation.NONE])
def test_the_assembled_jacobian_is_casadis_of_the_rows(setup, rel):
    """IPOPT's (and LM's) Jacobian of a subgraph's rows comes from the factors' own (``gnpp.assembly``): at
    random points within the variable bounds it equals CasADi's AD of the plain rows, entry by entry, and
    so does the one the built nlpsol evaluates. The graph has variables merged by ``presolve`` (one NLP
    variable in two slots of a factor) and factors with constant slots."""
    import casadi as ca

    from rlgp_exec.planning.gnpp.assembly import assemble

    lib, graph, _ = setup
    sub = relax(graph, rel)
    order = variables(sub)
    pre = presolve(lib, sub, order)
    rows = assemble(lib, sub, order, pre)
    x = rows.x
    mine = ca.Function("mine", [x], [ca.densify(ca.jacobian(rows.g, x))])
    ad = ca.Function("ad", [x], [ca.densify(ca.jacobian(rows.g_plain, x))])
    p = ca.MX.sym("p", x.numel())
    nlp = {"x": x, "p": p, "f": ca.sumsqr(x - p), "g": rows.g}
    jac_g = ca.nlpsol("s", "ipopt", nlp, {"ipopt.print_level": 0, "print_time": False}).get_function("nlp_jac_g")
    free = [order[i] for i in pre.free]
    bounds = [lib.var_bounds(v.kind, v.owner) for v in free]
    lo, hi = np.concatenate([b[0] for b in bounds]), np.concatenate([b[1] for b in bounds])
    lo, hi = np.maximum(lo, -3.0), np.minimum(hi, 3.0)
    rng = np.random.default_rng(0)
    assert rows.g.numel() == rows.lbg.size > 0
    for _ in range(3):
        xs = rng.uniform(lo, hi)
        want = np.asarray(ad(xs))
        assert np.count_nonzero(want) > 0
        np.testing.assert_allclose(np.asarray(mine(xs)), want, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(np.asarray(jac_g(xs, xs)[1]), want, rtol=1e-9, atol=1e-9)
