"""The symbolic layer: domain, problems from scenes, the Python successor model and search, Fast
Downward, and the GNPP reformulation (checked against a direct, compilation-free oracle)."""

from __future__ import annotations

import dataclasses
import sys
from collections import deque
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rlgp_exec.planning.symbolic import (
    ActionPattern,
    FDStatus,
    ForbiddenActions,
    ForbiddenSequence,
    GroundAction,
    GroundProblem,
    PartialState,
    SymbolicError,
    best_first,
    distance_cost,
    domain_to_pddl,
    goal_lower_bound,
    ground,
    ground_scene,
    ground_to_pddl,
    load_domain,
    parse_domain,
    problem_from_scene,
    problem_to_pddl,
    reformulate,
    run_fast_downward,
    solve_ground,
    solve_spec,
    violates,
)
from rlgp_exec.scene import load_scene

SCENES = sorted(Path(__file__).resolve().parents[1].joinpath("sim", "scenes").glob("*.toml"))
SCENE_IDS = [p.stem for p in SCENES]


@pytest.fixture(scope="module")
def scenes():
    return {p.stem: load_scene(p) for p in SCENES}


def test_all_scenes_present():
    assert {
        "pick_place_pr2",
        "sorting_pr2",
        "sorting_hsr",
        "table_clearing_hsr",
        "tower_pr2",
        "hanoi_pr2",
        "obstacles_tower_pr2",
    } <= set(SCENE_IDS)


# --- domain ---------------------------------------------------------------------------------------


def test_domain_round_trips_and_has_the_actions():
    d = load_domain()
    assert parse_domain(domain_to_pddl(d)) == d
    assert {a.name for a in d.actions} >= {"pick", "place", "stack", "drop", "take_knob", "open_drawer", "close_drawer"}
    assert d.subtypes("support") >= {"surface", "slot", "movable", "cabinet"}


def test_generated_domain_text_is_accepted_by_fast_downward(scenes):
    spec = problem_from_scene(scenes["sorting_hsr"])
    text = domain_to_pddl(parse_domain(domain_to_pddl(load_domain())))  # regenerated twice
    r = run_fast_downward(text, problem_to_pddl(spec), names={n.lower(): n for n, _ in spec.objects})
    assert r.status is FDStatus.SOLVED, r.reason
    assert ground(spec).reaches_goal(r.plan)


@pytest.mark.parametrize(
    "bad, what",
    [
        ("(define (domain x) (:action a :parameters (?x) :precondition (or (p ?x) (q ?x)) :effect (p ?x)))", "'or'"),
        (
            "(define (domain x) (:predicates (p ?x)) (:action a :parameters (?x) :precondition (p ?y) :effect (p ?x)))",
            "?y",
        ),
        ("(define (domain x) (:predicates (p ?x)) (:action a :parameters (?x) :effect (q ?x)))", "'q'"),
        ("(define (domain x) (:predicates (p ?x))", "unclosed"),
    ],
)
def test_malformed_domains_are_rejected_by_name(bad, what):
    with pytest.raises(SymbolicError) as e:
        parse_domain(bad)
    assert what in str(e.value)


# --- problems from scenes -------------------------------------------------------------------------


def test_problem_typing_and_initial_state(scenes):
    hanoi = problem_from_scene(scenes["hanoi_pr2"])
    types = dict(hanoi.objects)
    assert types["right_arm"] == types["left_arm"] == "manipulator"
    assert types["peg_left"] == "slot" and types["table"] == "surface" and types["d_small"] == "movable"
    assert ("on", "d_large", "peg_left") in hanoi.init  # on the table, inside the peg's region
    assert ("clear", "peg_mid") in hanoi.init and ("clear", "peg_left") not in hanoi.init
    assert ("stackable", "d_small", "d_mid") in hanoi.init
    assert ("stackable", "d_mid", "d_small") not in hanoi.init  # the Hanoi rule
    clearing = problem_from_scene(scenes["table_clearing_hsr"])
    assert dict(clearing.objects)["cabinet"] == "cabinet" and dict(clearing.objects)["arm"] == "manipulator"
    assert {("closed", "cabinet"), ("on", "cup", "cabinet"), ("knob-free", "cabinet")} <= clearing.init
    assert dict(problem_from_scene(scenes["pick_place_pr2"]).objects)["tray"] == "surface"


@pytest.mark.parametrize(
    "goal, names",
    [
        (["(on block_purple tray_blue)"], ["block_purple", "block_blue", "block_green"]),
        (["(on block_blue tray_pink)"], ["tray_pink", "tray_blue", "table_mid"]),
        (["(in block_blue table_mid)"], ["table_mid", "a surface"]),
        (["(stacked block_blue tray_blue)"], ["stacked", "on"]),
        (["(on block_blue)"], ["(on block_blue)", "2 argument"]),
        (["(on block_blue block_blue)"], ["itself"]),
        (["on block_blue tray_blue"], ["on block_blue tray_blue"]),
    ],
)
def test_bad_goals_name_the_literal(scenes, goal, names):
    with pytest.raises(SymbolicError) as e:
        problem_from_scene(scenes["sorting_hsr"], goal=goal)
    for n in names:
        assert n in str(e.value)


def test_scene_with_unknown_support_is_rejected(scenes):
    sc = scenes["sorting_hsr"]
    bad = dataclasses.replace(sc, objects=(dataclasses.replace(sc.objects[0], support="nowhere"),))
    with pytest.raises(SymbolicError, match="nowhere"):
        problem_from_scene(bad)


def test_simulate_reports_the_inapplicable_step(scenes):
    g = ground_scene(scenes["sorting_hsr"])
    with pytest.raises(SymbolicError, match=r"step 0 .*place.*missing"):
        g.simulate([GroundAction("place", ("arm", "block_blue", "tray_blue"))])
    with pytest.raises(SymbolicError, match="no ground action"):
        g.simulate([GroundAction("fly", ("arm",))])


# --- both searches solve every scene --------------------------------------------------------------


@pytest.mark.parametrize("name", SCENE_IDS)
def test_python_search_and_fast_downward_solve_every_scene(scenes, name):
    spec = problem_from_scene(scenes[name])
    g = ground(spec)
    assert not g.is_goal(g.init)
    it = best_first(g, max_expansions=20_000, heuristic=goal_lower_bound(g))
    plan = next(it)
    assert g.reaches_goal(plan.actions) and plan.cost == len(plan.actions)
    assert it.stats.expanded > 0 and it.stats.plans == 1
    fd = solve_spec(spec)
    assert fd.status is FDStatus.SOLVED, fd.reason
    assert g.reaches_goal(fd.plan)
    fd_ground = solve_ground(g, search="optimal")
    assert fd_ground.status is FDStatus.SOLVED and g.reaches_goal(fd_ground.plan)
    assert len(fd_ground.plan) == len(plan.actions)  # both optimal (admissible heuristic, unit costs)


def test_table_clearing_uses_the_drawer(scenes):
    g = ground_scene(scenes["table_clearing_hsr"])
    plan = next(best_first(g, heuristic=goal_lower_bound(g))).actions
    names = [a.name for a in plan]
    assert names[:2] == ["take_knob", "open_drawer"] and names[-2:] == ["take_knob", "close_drawer"]
    assert names.count("drop") == 2 and "pick" in names and len(plan) == 8
    fd = solve_ground(g)
    fd_names = [a.name for a in fd.plan]
    assert {"take_knob", "open_drawer", "drop", "close_drawer"} <= set(fd_names)
    assert fd_names.index("open_drawer") < fd_names.index("drop") < fd_names.index("close_drawer")


def test_goal_lower_bound_is_admissible_along_optimal_plans(scenes):
    for name in ("table_clearing_hsr", "tower_pr2", "hanoi_pr2"):
        g = ground_scene(scenes[name])
        h = goal_lower_bound(g)
        plan = next(best_first(g, heuristic=h))
        for i, s in enumerate(plan.states):
            assert h(s) <= len(plan.actions) - i, (name, i)
        assert h(plan.states[-1]) == 0


def test_candidates_come_in_cost_order_and_differ(scenes):
    g = ground_scene(scenes["sorting_hsr"])
    it = best_first(g, heuristic=goal_lower_bound(g), max_visits=3)
    plans = [next(it) for _ in range(5)]
    costs = [p.cost for p in plans]
    assert costs == sorted(costs) and costs[0] == 4 and costs[-1] > 4
    assert len({p.actions for p in plans}) == 5
    assert all(g.reaches_goal(p.actions) for p in plans)


def test_cost_fn_is_pluggable_and_changes_the_choice(scenes):
    g = ground_scene(scenes["sorting_hsr"])

    def hate_blue_first(prefix, action):
        return 10.0 if not prefix and "block_blue" in action.args else 1.0

    first = next(best_first(g, cost_fn=hate_blue_first)).actions
    assert first[0].args[1] == "block_green"
    other = next(best_first(g, cost_fn=lambda p, a: 10.0 if not p and "block_green" in a.args else 1.0)).actions
    assert other[0].args[1] == "block_blue"
    dist = next(best_first(g, cost_fn=distance_cost(scenes["sorting_hsr"]), heuristic=goal_lower_bound(g)))
    assert dist.cost > len(dist.actions) and g.reaches_goal(dist.actions)


def test_search_budget_and_exhaustion_are_reported(scenes):
    g = ground_scene(scenes["tower_pr2"])
    it = best_first(g, max_expansions=5)
    assert list(it) == [] and it.stats.budget_hit and it.stats.expanded == 5
    impossible = ground_scene(scenes["hanoi_pr2"], goal=["(on d_large d_small)"])
    it = best_first(impossible, max_expansions=50_000)
    assert list(it) == [] and it.stats.exhausted and not it.stats.budget_hit
    assert solve_ground(impossible).status is FDStatus.UNSOLVABLE


@pytest.mark.parametrize("name", ["table_clearing_hsr", "tower_pr2", "hanoi_pr2"])
def test_indexed_successors_equal_a_scan_of_every_operator(scenes, name):
    """``successors`` looks only at the operators one atom of the state triggers; along random walks
    (also on a reformulated task, whose operators have conditional effects) it must give exactly the
    applicable operators, in the operators' order, with the same successor states."""
    import random

    g = ground_scene(scenes[name])
    plan = next(best_first(g, heuristic=goal_lower_bound(g)))
    f = ForbiddenSequence((PartialState(plan.states[1]), PartialState(plan.states[2])))
    for task in (g, reformulate(g, [f]).problem):
        rng = random.Random(0)
        for _ in range(5):
            s = task.init
            for _ in range(12):
                scan = [(op.action, op.apply(s)) for op in task.operators if op.applicable(s)]
                if task.required:
                    scan = [(a, t) for a, t in scan if task.required <= t]
                assert task.successors(s) == scan
                if not scan:
                    break
                s = rng.choice(scan)[1]


# --- Fast Downward failure statuses ----------------------------------------------------------------


def test_fast_downward_missing_binary_and_timeout(scenes, tmp_path):
    spec = problem_from_scene(scenes["sorting_hsr"])
    dom, prob = domain_to_pddl(load_domain()), problem_to_pddl(spec)
    r = run_fast_downward(dom, prob, script=tmp_path / "nope" / "fast-downward.py")
    assert r.status is FDStatus.MISSING_BINARY and "nope" in r.reason
    sleeper = tmp_path / "fd.py"
    sleeper.write_text("import time\ntime.sleep(30)\n")
    r = run_fast_downward(dom, prob, script=sleeper, timeout_s=0.5)
    assert r.status is FDStatus.TIMEOUT and r.wall_time_s < 10
    crasher = tmp_path / "crash.py"
    crasher.write_text("import sys\nprint('Error: boom', file=sys.stderr)\nsys.exit(3)\n")
    r = run_fast_downward(dom, prob, script=crasher)
    assert r.status is FDStatus.ERROR and "boom" in r.reason
    r = run_fast_downward(dom, "(define (problem broken)", timeout_s=20)
    assert r.status is not FDStatus.SOLVED and r.reason
    assert run_fast_downward(dom, prob, search="bogus").status is FDStatus.ERROR
    assert sys.executable  # the driver runs under this interpreter


# --- GNPP reformulation ---------------------------------------------------------------------------


def _oracle_solvable(g: GroundProblem, forbidden) -> bool:
    """BFS over (state, matcher state) computed straight from the definition, no compilation."""
    seqs = [f for f in forbidden if isinstance(f, ForbiddenSequence)]
    sets = [f for f in forbidden if isinstance(f, ForbiddenActions)]

    def step_seq(active, s):
        out = []
        for f, act in zip(seqs, active, strict=True):
            new = frozenset(lvl for lvl, p in enumerate(f.states) if p.holds(s) and (lvl == 0 or lvl - 1 in act))
            if len(f.states) - 1 in new:
                return None
            out.append(new)
        return tuple(out)

    def step_set(seen, a):
        out = []
        for f, sn in zip(sets, seen, strict=True):
            new = sn | frozenset(p for p in f.patterns if p.matches(a))
            if new == f.patterns:
                return None
            out.append(new)
        return tuple(out)

    start_seq = step_seq(tuple(frozenset() for _ in seqs), g.init)
    if start_seq is None:
        return False
    start = (g.init, start_seq, tuple(frozenset() for _ in sets))
    seen_nodes = {start}
    queue = deque([start])
    while queue:
        s, act, sn = queue.popleft()
        if g.is_goal(s):
            return True
        for a, s2 in g.successors(s):
            act2, sn2 = step_seq(act, s2), step_set(sn, a)
            if act2 is None or sn2 is None:
                continue
            node = (s2, act2, sn2)
            if node not in seen_nodes:
                seen_nodes.add(node)
                queue.append(node)
    return False


@pytest.fixture(scope="module")
def small():
    scene = load_scene(next(p for p in SCENES if p.stem == "sorting_hsr"))
    g = ground_scene(scene, goal=["(on block_blue tray_blue)"])
    plan = next(best_first(g, heuristic=goal_lower_bound(g)))
    return g, plan


def test_forbidding_the_goal_state_makes_the_problem_unsolvable(small):
    g, _ = small
    ref = reformulate(g, [ForbiddenSequence((PartialState(g.goal),))])
    assert solve_ground(ref.problem).status is FDStatus.UNSOLVABLE
    it = best_first(ref.problem, max_expansions=10_000)
    assert list(it) == [] and it.stats.exhausted


def test_forbidding_one_placement_finds_a_detour(small):
    g, plan = small
    # the paper's Fig. 4 (left): picking block_blue from table_mid is infeasible while block_green is there
    f = ForbiddenSequence(
        (
            PartialState.of(["(on block_blue table_mid)", "(on block_green table_mid)"]),
            PartialState.of(["(holding arm block_blue)"]),
        )
    )
    assert f.occurs_in(plan.states)
    ref = reformulate(g, [f])
    fd = solve_ground(ref.problem)
    assert fd.status is FDStatus.SOLVED
    states = g.simulate(fd.plan)
    assert g.is_goal(states[-1]) and not violates(fd.plan, states, [f])
    assert fd.plan[0].args[1] == "block_green"  # moves the other block first
    py = next(best_first(ref.problem, heuristic=goal_lower_bound(g)))
    assert g.reaches_goal(py.actions) and not f.occurs_in(g.simulate(py.actions))
    assert len(py.actions) == 4 and len(fd.plan) >= 4


def test_forbidden_action_sets(small, scenes):
    g, plan = small
    # every plan of the small problem picks block_blue from table_mid and places it on tray_blue
    f = ForbiddenActions(frozenset({ActionPattern.of(a) for a in plan.actions}))
    assert solve_ground(reformulate(g, [f]).problem).status is FDStatus.UNSOLVABLE
    assert not _oracle_solvable(g, [f])
    two_hands = ground_scene(scenes["pick_place_pr2"], goal=["(on block_a tray)"])
    right = ForbiddenActions(frozenset({ActionPattern.of("(pick right_arm block_a *)")}))
    ref = reformulate(two_hands, [right])
    fd = solve_ground(ref.problem)
    assert fd.status is FDStatus.SOLVED and two_hands.reaches_goal(fd.plan) and not right.occurs_in(fd.plan)
    assert fd.plan[0] == GroundAction("pick", ("left_arm", "block_a", "table"))
    any_hand = ForbiddenActions(frozenset({ActionPattern.of("(pick * block_a table)")}))
    assert solve_ground(reformulate(two_hands, [any_hand]).problem).status is FDStatus.UNSOLVABLE
    with pytest.raises(SymbolicError, match="fly"):
        reformulate(g, [ForbiddenActions(frozenset({ActionPattern("fly", ())}))])
    with pytest.raises(SymbolicError, match="already"):
        reformulate(ref.problem, [f])


def test_ground_pddl_has_conditional_effects_only_when_reformulated(small):
    g, plan = small
    assert not ground_to_pddl(g).conditional_effects
    text = ground_to_pddl(reformulate(g, [ForbiddenSequence((PartialState(plan.states[1]),))]).problem)
    assert text.conditional_effects and "(when" in text.domain


@st.composite
def forbidden_sets(draw, g, plan):
    """Forbidden patterns cut from the first plan (so they bite) plus random atoms."""
    universe = sorted(set().union(*plan.states))
    out = []
    for _ in range(draw(st.integers(1, 2))):
        if draw(st.booleans()):
            L = draw(st.integers(0, 2))
            i = draw(st.integers(0, len(plan.states) - 1 - L))
            parts = []
            for k in range(L + 1):
                atoms = sorted(plan.states[i + k])
                chosen = draw(st.sets(st.sampled_from(atoms), min_size=1, max_size=2))
                if draw(st.booleans()):
                    chosen |= {draw(st.sampled_from(universe))}
                parts.append(PartialState(frozenset(chosen)))
            out.append(ForbiddenSequence(tuple(parts)))
        else:
            picks = draw(st.sets(st.sampled_from(plan.actions), min_size=1, max_size=2))
            pats = {
                ActionPattern(a.name, tuple(None if draw(st.booleans()) and j > 0 else x for j, x in enumerate(a.args)))
                for a in picks
            }
            out.append(ForbiddenActions(frozenset(pats)))
    return out


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_reformulation_forbids_exactly_the_forbidden_plans(small, data):
    g, plan = small
    forbidden = data.draw(forbidden_sets(g, plan))
    ref = reformulate(g, forbidden)
    assert violates(plan.actions, plan.states, forbidden) == any(
        f.occurs_in(plan.states) if isinstance(f, ForbiddenSequence) else f.occurs_in(plan.actions) for f in forbidden
    )
    solvable = _oracle_solvable(g, forbidden)
    fd = solve_ground(ref.problem)
    it = best_first(ref.problem, max_expansions=50_000, heuristic=goal_lower_bound(g))
    py = next(it, None)
    if solvable:
        assert fd.status is FDStatus.SOLVED, (forbidden, fd.reason)
        states = g.simulate(fd.plan)
        assert g.is_goal(states[-1]) and not violates(fd.plan, states, forbidden)
        assert py is not None
        py_states = g.simulate(py.actions)
        assert g.is_goal(py_states[-1]) and not violates(py.actions, py_states, forbidden)
        assert [ref.project(s) for s in py.states] == py_states
    else:
        assert fd.status is FDStatus.UNSOLVABLE, forbidden
        assert py is None and it.stats.exhausted
