"""GNPP: a conflict's partial states generalised along its objects' Equal chains (``graph.generalise``):
every plan that contains the generalised sequence has a subgraph that is the conflict's NLP."""

from __future__ import annotations

import pytest
from test_gnpp import _plans, _tower  # tests/ is on sys.path (pytest, rootless test modules)

from rlgp_exec.planning.gnpp.graph import generalise, structure, to_forbidden
from rlgp_exec.planning.gnpp.pntc import Factor, Var, add_flags, factors_of
from rlgp_exec.planning.symbolic import GroundAction, ground_scene

ARMS = ["left_arm", "right_arm"]
OBJECTS = ["b1", "b2"]
#: (plan, the factors of its graph that make the conflict, by their text)
CASES = {
    # b1 held two steps, then put on the goal region by the left arm
    "place": (
        ["(pick left_arm b1 table)", "(pick right_arm b2 table)", "(place left_arm b1 goal_region)"],
        [
            "Grasp/b1(x[b1]@1)",
            "Equal/4(x[b1]@1, x[b1]@2)",
            "Kin/b1/left_arm(q[left_arm]@3, x[b1]@3, x[b1]@2)",
            "Place/b1/goal_region(x[b1]@3)",
            "ColFix/left_arm(q[left_arm]@3)",
        ],
    ),
    # b2 stacked by the right arm on b1, which the left arm put on the goal region two steps before
    "stack": (
        [
            "(pick left_arm b1 table)",
            "(place left_arm b1 goal_region)",
            "(pick right_arm b2 table)",
            "(stack right_arm b2 b1)",
        ],
        [
            "Place/b1/goal_region(x[b1]@2)",
            "Equal/4(x[b1]@2, x[b1]@3)",
            "Equal/4(x[b1]@3, x[b1]@4)",
            "Grasp/b2(x[b2]@3)",
            "Kin/b2/right_arm(q[right_arm]@4, x[b2]@4, x[b2]@3)",
            "On/b2/b1(x[b2]@4, x[b1]@4)",
        ],
    ),
}


@pytest.fixture(scope="module")
def task():
    scene = _tower(OBJECTS, ["(on b1 goal_region)"])
    return add_flags(ground_scene(scene, manipulators=ARMS))


def _conflict(task, case: str) -> list[Factor]:
    plan, texts = CASES[case]
    states = task.simulate([GroundAction.parse(a) for a in plan])
    graph = {str(f): f for f in factors_of(states, ARMS, OBJECTS)}
    return [graph[t] for t in texts]


def _shift(v: Var, dt: int) -> Var:
    return Var(v.kind, v.owner, v.t + dt)


def _implied(graph: list[Factor], conflict: tuple[Factor, ...], dt: int) -> list[Factor] | None:
    """The subgraph of a plan's ``graph`` that ``conflict`` (a generalised one) shifted by ``dt`` steps
    stands for: each factor itself, or a moved Grasp / Place where the plan has it, earlier on its
    object's Equal chain (with the chain); None if a factor has neither."""
    by_key = {(f.key, f.vars): f for f in graph}
    equal_into = {f.vars[1]: f for f in graph if f.kind == "Equal"}
    out: list[Factor] = []
    for f in conflict:
        vs = tuple(_shift(v, dt) for v in f.vars)
        if (f.key, vs) in by_key:
            out.append(by_key[(f.key, vs)])
            continue
        if len(vs) != 1:
            return None
        v, chain = vs[0], []
        while (f.key, (v,)) not in by_key and v in equal_into:
            chain.append(equal_into[v])
            v = equal_into[v].vars[0]
        if (f.key, (v,)) not in by_key:
            return None
        out += [by_key[(f.key, (v,))], *chain]
    return out


@pytest.mark.parametrize("case", sorted(CASES))
def test_generalised_conflict_is_implied_by_every_plan_containing_it(task, case):
    conflict = _conflict(task, case)
    general = generalise(conflict)
    assert not any(f.kind == "Equal" for f in general)  # the chains dropped
    assert structure(general) == structure(conflict)  # the same NLP
    seq, narrow = to_forbidden(general), to_forbidden(conflict)
    assert len(seq.states) < len(narrow.states)
    n_general = n_narrow = 0
    for _, states in _plans(task, 5):
        n_narrow += narrow.occurs_in(states)
        hits = [i for i in range(len(states)) if seq.occurs_in(states[i : i + len(seq.states)])]
        if not hits:
            continue
        n_general += 1
        graph = factors_of(states, ARMS, OBJECTS)
        lo = min(t for f in general for t, _ in f.partial)
        for i in hits:
            sub = _implied(graph, general, i - lo)
            assert sub is not None and structure(sub) == structure(conflict), (i, states)
    assert n_general > n_narrow > 0  # strictly more plans forbidden, each of them infeasible


def test_generalise_leaves_other_factors_and_unchained_poses():
    o = "b1"
    x1, x2, q = Var("x", o, 1), Var("x", o, 2), Var("q", "left_arm", 2)
    kin = Factor(("Kin", o, "left_arm"), (q, x1, x2), ())
    ref = Factor(("Ref", o), (x1,), ())
    assert generalise([ref, kin]) == (ref, kin)
