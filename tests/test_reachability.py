"""Reachability graph: valid nodes, no path through a wall, the library, persistence, cache checks."""

from __future__ import annotations

import itertools
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from rlgp_exec.errors import RlgpError
from rlgp_exec.reach import (
    GraphCacheError,
    QueryStatus,
    ReachabilityGraph,
    ReachabilityPlanner,
    ReachIK,
    RGParams,
    WorldChecker,
    build_graph,
    interpolate,
    load_or_build,
    nominal_q,
)
from rlgp_exec.reach.build import graph_meta
from rlgp_exec.reach.ik import POS_TOL
from rlgp_exec.reach.ompl_plan import drive_base, drive_postures, plan_ompl
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import load_scene

ROOT = Path(__file__).resolve().parent
WALL = ROOT / "data" / "wall_hsr.toml"
SORTING = ROOT.parent / "sim" / "scenes" / "sorting_hsr.toml"
PARAMS = RGParams(samples=60, k=8, seed=3)


@pytest.fixture(scope="module")
def wall():
    scene = load_scene(WALL)
    model = load_robot("hsr")
    graph, stats = build_graph(scene, params=PARAMS, workers=1)
    checker = WorldChecker(scene, model.manipulator().group)
    planner = ReachabilityPlanner(graph, ReachIK(model, scene, nominal_q(model, scene)), checker, rng_seed=0)
    yield scene, model, graph, stats, checker, planner
    checker.close()


def replay_is_collision_free(scene, graph, path) -> bool:
    from rlgp_exec.world.pybullet_world import build_world

    world = build_world(replace(scene, objects=()), tags=False)
    try:
        fine = np.vstack([interpolate(graph, a, b, 0.0025) for a, b in itertools.pairwise(path)])
        return not any(world.robot.in_collision(q) for q in fine)
    finally:
        world.close()


def test_every_node_reaches_its_point_and_is_collision_free(wall):
    _scene, model, graph, stats, checker, _ = wall
    assert graph.G.number_of_nodes() == PARAMS.samples and stats.attempts >= PARAMS.samples
    tool = model.manipulator().tool_frame
    for i in graph.alive:
        assert np.linalg.norm(model.fk(graph.Q[i], tool)[:3, 3] - graph.X[i]) <= POS_TOL
        assert not checker(graph.Q[i])
    assert all(graph.G.degree(i) > 0 for i in graph.alive)


def test_a_path_never_goes_through_the_wall(wall):
    scene, _model, graph, _, checker, planner = wall
    left = [i for i in graph.alive if graph.X[i][0] < -0.4 and graph.X[i][1] > -0.3]
    right = [i for i in graph.alive if graph.X[i][0] > 0.4 and graph.X[i][1] > -0.3]
    assert left and right
    a, b = left[0], right[0]
    # the straight configuration-space motion between them crosses the wall
    assert checker.edge_collides(graph.Q[a], graph.Q[b])
    res = planner.query(graph.X[a], graph.X[b])
    assert res.status is QueryStatus.OK, res.reason
    assert np.allclose(res.path[0], graph.Q[a]) and np.allclose(res.path[-1], graph.Q[b])
    assert replay_is_collision_free(scene, graph, res.path)
    # a detour: the base goes round one end of the wall (y from -0.7 to 1.7; base radius 0.215)
    assert res.path[:, 1].min() < -0.7 - 0.2 or res.path[:, 1].max() > 1.7 + 0.2


def test_an_edge_is_free_exactly_when_its_fixed_and_changed_parts_are(wall):
    """The split check the planner uses while objects stand or one is held (graph verdict + the rest)
    agrees with the whole check."""
    from rlgp_exec.scene.geometry import object_box

    scene, _model, graph, _, checker, _ = wall
    box = object_box(scene.objects[0])
    others = [
        replace(box, T=T) for T in (box.T, np.array([[1, 0, 0, 0.0], [0, 1, 0, 0.3], [0, 0, 1, 0.5], [0, 0, 0, 1]]))
    ]
    edges = list(graph.G.edges)[:40]
    try:
        for held in (False, True):
            checker.set_objects(others)
            if held:
                checker.attach(
                    np.array([0.05, 0.05, 0.08]),
                    np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.04], [0, 0, 0, 1.0]]),
                )
            whole = [checker.edge_collides(graph.Q[i], graph.Q[j]) for i, j in edges]
            split = [
                checker.edge_collides(graph.Q[i], graph.Q[j], part="fixed")
                or checker.edge_collides(graph.Q[i], graph.Q[j], part="changed")
                for i, j in edges
            ]
            assert whole == split
            assert any(whole) and not all(whole)
    finally:
        checker.detach()
        checker.set_objects([])


def test_a_link_the_edge_does_not_move_does_not_slow_its_sweep(wall):
    """Conservative advancement per link: with the base 11 mm from the wall (the closest link, facing
    away), turning a wrist joint moves no base point, so the sweep takes a few large steps instead of
    ~40 steps of the base's margin; turning the base in place moves its body by its own radius, not the
    arm's reach. The verdicts stay exact: free, and no sample of a dense sweep comes within the
    clearance."""
    import math

    scene, model, _, _, checker, _ = wall
    q = nominal_q(model, scene).copy()
    q[:3] = (-0.05 - 0.215 - 0.011, 0.5, math.pi)  # wall face at x = -0.05, base radius 0.215 m
    assert checker.distance(q) < 0.02 and not checker(q)
    for joint, delta, most in (("arm_roll_joint", 0.3, 10), ("wrist_flex_joint", 0.3, 10), ("base_yaw", 0.5, 40)):
        q2 = q.copy()
        q2[model.index(joint)] += delta
        calls = checker.calls
        assert not checker.edge_collides(q, q2)
        assert checker.calls - calls <= most, joint
        dq = model.limits.difference(q2, q)
        assert all(checker.distance(q + s * dq) >= checker.clearance for s in np.linspace(0.0, 1.0, 200))


def test_the_library_answers_both_directions(wall):
    _, _, graph, _, _, planner = wall
    a, b = graph.alive[5], graph.alive[40]
    first = planner.query(graph.X[a], graph.X[b])
    assert first.ok and not first.cached
    back = planner.query(graph.X[b], graph.X[a])
    assert back.cached and np.array_equal(back.path, first.path[::-1]) and back.cost == first.cost
    again = planner.query(graph.X[a], graph.X[b])
    assert again.cached and np.array_equal(again.path, first.path)
    assert planner.heuristic_cost(graph.X[b], graph.X[a]) == first.cost


def test_unreachable_targets_are_statuses(wall):
    _, _, graph, _, _, planner = wall
    inside_wall = np.array([0.0, 0.5, 0.8])
    far_away = np.array([9.0, 9.0, 2.5])  # the base can drive anywhere, but not lift the hand to 2.5 m
    assert planner.query(inside_wall, graph.X[graph.alive[0]]).status is QueryStatus.START_UNREACHABLE
    assert planner.query(graph.X[graph.alive[0]], far_away).status is QueryStatus.GOAL_UNREACHABLE


def _fresh_planner(wall, seed: int = 1) -> ReachabilityPlanner:
    """A planner on a copy of the fixture's graph (the tests below cut edges)."""
    import copy

    scene, model, graph, _, checker, _ = wall
    g = copy.deepcopy(graph)
    return ReachabilityPlanner(g, ReachIK(model, scene, nominal_q(model, scene)), checker, rng_seed=seed)


def test_a_node_cut_off_by_hidden_edges_is_bridged_back(wall):
    """While carrying, an edge free of the fixtures may be hidden for the query (too tight for the held
    object): a node whose edges are all hidden is in the graph's component but cut off for the query.
    A bridge must join it to the rest as the query sees the graph, through a new node with checked
    edges, not sample round a pair inside one component."""
    import networkx as nx

    planner = _fresh_planner(wall)
    g = planner.g
    a = int(g.alive[7])
    b = max(g.alive, key=lambda i: float(np.linalg.norm(g.X[i] - g.X[a])))
    for n in list(g.G.neighbors(a)):
        planner._carry_verdicts[(min(a, n), max(a, n))] = False

    def open_view():
        def shown(u: int, v: int) -> bool:
            return planner._carry_verdicts.get((min(u, v), max(u, v))) is not False

        return nx.subgraph_view(g.G, filter_edge=shown)

    assert nx.has_path(g.G, a, b) and not nx.has_path(open_view(), a, b)
    assert planner._bridge(a, b)
    assert nx.has_path(open_view(), a, b)
    new = [n for n in g.G.neighbors(a) if planner._carry_verdicts.get((min(a, n), max(a, n))) is not False]
    assert new and all(g.G.edges[a, n]["checked"] for n in new)


def test_a_bridge_that_finds_nothing_gives_up_after_its_ik_budget(wall, monkeypatch):
    """Every configuration colliding (the held object's world, say), a bridge's task-space stage stops
    after BRIDGE_IK_SOLVES IK solves, for the query's OMPL fallback: uncapped it ran ~500 (8 s)."""
    import rlgp_exec.reach.query as query

    planner = _fresh_planner(wall)
    g = planner.g
    a = int(g.alive[7])
    b = max(g.alive, key=lambda i: float(np.linalg.norm(g.X[i] - g.X[a])))
    solves = []
    solve = planner.ik.solve
    monkeypatch.setattr(planner.ik, "solve", lambda *args, **kw: solves.append(1) or solve(*args, **kw))
    monkeypatch.setattr(planner, "in_collision", lambda q: True)
    cap = query.BRIDGE_IK_SOLVES
    assert not planner._bridge(a, b)
    assert len(solves) == cap
    monkeypatch.setattr(query, "BRIDGE_IK_SOLVES", 3 * cap)  # the budget, not the samples, ended it
    solves.clear()
    assert not planner._bridge(a, b)
    assert len(solves) == 3 * cap


def test_a_configured_end_joins_its_joint_space_neighbours(wall):
    """An end given with its configuration (the robot's, a keyframe's) is connected to the nodes nearest
    in joint space as well as in task space: a posture next to a node's, with the hand moved away from
    that node's point, still gets an edge to it."""
    planner = _fresh_planner(wall)
    g, model = planner.g, planner.ik.model
    i = int(g.alive[3])
    q = g.Q[i].copy()
    q[g.plan_idx[3]] += 0.6  # the first arm joint: the hand swings away, the posture stays near node i's
    x = model.fk(q, model.manipulator().tool_frame)[:3, 3]
    n = planner.insert(x, q)
    assert n is not None
    assert i in g.G[n]
    assert set(g.nearest_q(q, g.params.k, exclude=n)) <= set(g.G[n])


def test_a_sampled_configuration_is_a_node_as_ik_would_validate_it(wall):
    """``ReachIK.node_at`` (bridges and enhancements sample in joint space): the hand's position of a
    graph node's configuration is that node's point, and a base inside a fixture's footprint is refused
    like the IK refuses it."""
    scene, _model, graph, _, _, planner = wall
    for i in graph.alive[:10]:
        node = planner.ik.node_at(graph.Q[i])
        assert node is not None
        assert np.linalg.norm(node[0] - graph.X[i]) <= POS_TOL and 0.0 <= node[1] <= graph.C[i] + 1e-6
    q = graph.Q[graph.alive[0]].copy()
    q[:2] = scene.fixtures[0].T[:2, 3]  # the base on a table's centre
    assert planner.ik.node_at(q) is None


def test_ompl_plans_a_certified_path_round_the_wall(wall):
    _, _, graph, _, checker, _ = wall
    left = [i for i in graph.alive if graph.X[i][0] < -0.4]
    right = [i for i in graph.alive if graph.X[i][0] > 0.4]
    path = plan_ompl(
        checker,
        graph.plan_idx,
        graph.Q[left[0]],
        graph.Q[right[0]],
        np.array([-2.0, -2.0]),
        np.array([2.0, 2.0]),
        timeout=30.0,
    )
    assert path is not None
    assert not any(checker.edge_collides(a, b) for a, b in itertools.pairwise(path))


def test_drive_base_goes_round_the_wall_with_the_arm_held(wall):
    """drive_base (R-LGP's last-resort drive, GNPP's end-move): the base alone round the wall, the arm
    held in one of drive_postures while it drives; every motion passes the exact check."""
    _, _, graph, _, checker, _ = wall
    left = [i for i in graph.alive if graph.X[i][0] < -0.4]
    right = [i for i in graph.alive if graph.X[i][0] > 0.4]
    q1, q2 = graph.Q[left[0]], graph.Q[right[0]]
    rigid, postures = drive_postures(checker.model, q1, q2, empty_hand=True)
    lo, hi = np.array([-2.0, -2.0]), np.array([2.0, 2.0])
    path = drive_base(checker, q1, q2, rigid, postures, lo, hi, timeout=30.0)
    assert path is not None and np.array_equal(path[0], q1) and np.array_equal(path[-1], q2)
    assert not any(checker.edge_collides(a, b) for a, b in itertools.pairwise(path))
    middle = path[1:-1]
    assert np.allclose(middle[:, rigid], middle[0, rigid])  # one posture while the base drives


def test_ompl_moves_every_joint_that_differs_and_accepts_an_end_a_hair_past_a_limit(wall):
    """The ends of a guided segment may differ in a joint the graph does not plan (the PR2's torso raised
    for a vertical approach), and an optimiser's keyframe may sit ~1e-8 past a bound: the path must start and
    end exactly at the given configurations, every joint included."""
    _, model, graph, _, checker, _ = wall
    other = model.index("head_pan_joint")  # (the PR2's torso, in the planner; the HSR plans its lift)
    assert other not in set(graph.plan_idx.tolist())
    roll = model.index("wrist_roll_joint")

    def ends(nodes, past_limit: bool):
        for i in nodes:
            q = graph.Q[i].copy()
            if past_limit:
                q[roll] = model.limits.upper[roll] + 1e-8  # as IPOPT's bound relaxation leaves it
            else:
                q[other] += 0.3
            if not checker(q):
                return q
        raise AssertionError("no free end")

    q1 = ends([i for i in graph.alive if graph.X[i][0] < -0.4], True)
    q2 = ends([i for i in graph.alive if graph.X[i][0] > 0.4], False)
    path = plan_ompl(checker, graph.plan_idx, q1, q2, np.array([-2.0, -2.0]), np.array([2.0, 2.0]), timeout=30.0)
    assert path is not None
    np.testing.assert_allclose(path[0], q1, atol=1e-9)
    np.testing.assert_allclose(path[-1], q2, atol=1e-9)
    assert not any(checker.edge_collides(a, b) for a, b in itertools.pairwise(path))


def test_ompl_reaches_an_end_closer_to_a_fixture_than_its_own_states_keep(wall):
    """A grasp's approach may stand nearer a fixture than OMPL's clearance (3x the graph's): OMPL plans
    to a nudged configuration nearby and the path still ends exactly at the given one, every motion
    certified."""
    from rlgp_exec.reach.checker import CLEARANCE
    from rlgp_exec.reach.ompl_plan import OMPL_CLEARANCE

    _, _, graph, _, checker, _ = wall
    left = [i for i in graph.alive if graph.X[i][0] < -0.4]
    q2 = None
    for i in sorted(graph.alive, key=lambda i: -graph.X[i][0]):  # nodes right of the wall, nearest first
        if graph.X[i][0] < 0.2:
            continue
        q = graph.Q[i].copy()
        for _ in range(300):  # the base towards the wall, 2 mm at a time
            d = checker.distance(q)
            if d < CLEARANCE + 0.002:
                break
            if d < OMPL_CLEARANCE and not checker(q):
                q2 = q
                break
            q = q.copy()
            q[0] -= 0.002
        if q2 is not None:
            break
    assert q2 is not None
    path = plan_ompl(
        checker, graph.plan_idx, graph.Q[left[0]], q2, np.array([-2.0, -2.0]), np.array([2.0, 2.0]), timeout=30.0
    )
    assert path is not None
    np.testing.assert_allclose(path[-1], q2, atol=1e-9)
    assert not any(checker.edge_collides(a, b) for a, b in itertools.pairwise(path))


def test_a_saved_graph_reloads_identical_and_bad_files_are_refused(wall, tmp_path):
    scene, model, graph, _, _, _ = wall
    meta = graph_meta(model, scene, model.manipulator().name, PARAMS)
    path = graph.save(tmp_path / "g.npz")
    again = ReachabilityGraph.load(path, model.limits, meta)
    assert again.same_as(graph)
    with pytest.raises(GraphCacheError, match="scene_hash"):
        ReachabilityGraph.load(path, model.limits, {**meta, "scene_hash": "0" * 64})
    with pytest.raises(GraphCacheError, match="params"):
        ReachabilityGraph.load(path, model.limits, {**meta, "params": {**meta["params"], "k": 9}})
    bad = tmp_path / "bad.npz"
    bad.write_bytes(path.read_bytes()[:200])
    with pytest.raises(GraphCacheError, match="not a readable"):
        ReachabilityGraph.load(bad, model.limits, meta)
    # arrays tampered with: an edge to a node that does not exist
    with np.load(path) as z:
        arrays = dict(z)
    arrays["edges"] = np.vstack([arrays["edges"], [0, 10_000]])
    arrays["checked"] = np.r_[arrays["checked"], False]
    np.savez(tmp_path / "tampered.npz", **arrays)
    with pytest.raises(GraphCacheError, match="inconsistent"):
        ReachabilityGraph.load(tmp_path / "tampered.npz", model.limits, meta)


def test_load_or_build_uses_a_good_cache_and_rebuilds_a_corrupt_one(tmp_path):
    scene = load_scene(SORTING)
    params = RGParams(samples=12, seed=1)
    g1, s1 = load_or_build(scene, params=params, workers=1, folder=tmp_path)
    assert not s1.from_cache
    g2, s2 = load_or_build(scene, params=params, workers=1, folder=tmp_path)
    assert s2.from_cache and g2.same_as(g1)
    (cache,) = tmp_path.glob("*.npz")
    cache.write_bytes(b"garbage")
    g3, s3 = load_or_build(scene, params=params, workers=1, folder=tmp_path)
    assert not s3.from_cache and g3.G.number_of_nodes() == 12


@pytest.mark.parametrize("scene_file", ["pick_place_pr2.toml", "sorting_hsr.toml"])
def test_ik_tolerance_gives_the_verdicts_of_a_tighter_one(scene_file):
    """The IK's IPOPT tolerance (IK_TOL) accepts and refuses the same random targets as a 10x tighter
    one, and what it accepts puts the tool within POS_TOL of the target."""
    scene = load_scene(SORTING.parent / scene_file)
    model = load_robot(scene.robot.name)
    q0 = nominal_q(model, scene)
    ik, tight = ReachIK(model, scene, q0), ReachIK(model, scene, q0, tol=1e-6)
    rng = np.random.default_rng(1)
    tool = model.manipulator().tool_frame
    for _ in range(25):
        x = np.array([rng.uniform(-1.0, 1.0), rng.uniform(-1.0, 1.0), rng.uniform(0.4, 1.2)])
        z0 = ik.guess(x, rng.uniform(-np.pi, np.pi))
        a, b = ik.solve(x, z0), tight.solve(x, z0)
        assert a.ok == b.ok, (x, a.reason, b.reason)
        if a.ok:
            assert np.linalg.norm(model.fk(a.q, tool)[:3, 3] - x) <= POS_TOL


def _eager_sweep(checker, q1, q2, part):
    """The reference sweep: every link (and the held object) measured at every sample, the next sample
    where the first of them could have moved its distance less the clearance (no self-collision)."""
    import pybullet as p

    from rlgp_exec.reach.sweep import LOOKAHEAD, MIN_ADVANCE

    pairs = checker._pairs(part)
    dq = checker.model.limits.difference(q2, q1)
    links_bound, held_bound = checker._bounds(dq, part, q1)
    robot, c, s = checker.robot.id, checker.clearance, 0.0
    while True:
        q = q1 + s * dq
        checker._place(q, pairs)
        links, held = np.full(links_bound.shape, LOOKAHEAD), LOOKAHEAD
        for a, b in pairs:
            for pt in p.getClosestPoints(a, b, LOOKAHEAD, physicsClientId=checker.client):
                if a != robot:
                    held = min(held, pt[8])
                elif not (b == checker.knob and pt[3] in checker.finger_links and pt[4] == 0):
                    links[pt[3] + 1] = min(links[pt[3] + 1], pt[8])
        if min(links.min(), held) < c + MIN_ADVANCE * (s < 1.0):
            return True
        if s >= 1.0:
            return False
        with np.errstate(divide="ignore"):
            step = float(np.where(links_bound > 0, (links - c) / links_bound, np.inf).min())
        if held_bound > 0:
            step = min(step, (held - c) / held_bound)
        s = min(1.0, s + max(step, 1e-6))


def test_the_lazy_sweep_gives_the_verdicts_of_one_measuring_every_link(wall):
    """``edge_collides`` re-measures only the links that limit its next step (and moves the obstacles
    rather than the base): against a sweep that measures every link at every sample (self-collision
    aside), the same verdicts on edges round the wall, with objects standing and one held; a free edge
    keeps the clearance at 200 samples."""
    import pybullet as p

    from rlgp_exec.scene.geometry import object_box

    scene, model, graph, _, checker, _ = wall
    rng = np.random.default_rng(7)
    box = object_box(scene.objects[0])
    nodes = list(graph.alive)
    edges = [(graph.Q[i], graph.Q[j]) for i, j in list(graph.G.edges)[:25]]
    for _ in range(25):  # short random motions from nodes, some into the wall or the objects
        q = graph.Q[nodes[rng.integers(len(nodes))]]
        step = rng.normal(0.0, 0.3, q.size) * (graph.limits.upper > graph.limits.lower)
        edges.append((q, graph.limits.wrap(q + step)))
    tool = model.manipulator().tool_frame
    boxes = []  # objects where the hand passes a third of the way along some of the edges
    for q1, q2 in edges[::5]:
        T = np.eye(4)
        T[:3, 3] = model.fk(q1 + model.limits.difference(q2, q1) / 3, tool)[:3, 3] + [0.0, 0.0, 0.05]
        boxes.append(replace(box, T=T))
    try:
        checker.set_objects(boxes)
        homes = [p.getBasePositionAndOrientation(b, physicsClientId=checker.client) for b in checker.bodies]
        for held in (False, True):
            if held:
                checker.attach(np.array([0.05, 0.05, 0.08]), np.array(
                    [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.04], [0, 0, 0, 1.0]]))
            verdicts = []
            for q1, q2 in edges:
                lazy = checker.edge_collides(q1, q2, part="changed")
                assert lazy == _eager_sweep(checker, q1, q2, "changed")
                whole = checker.edge_collides(q1, q2)
                if not whole:
                    dq = model.limits.difference(q2, q1)
                    assert all(checker.distance(q1 + s * dq) >= checker.clearance for s in np.linspace(0, 1, 200))
                elif not checker.edge_collides(q1, q2, part="fixed"):
                    assert _eager_sweep(checker, q1, q2, "all")
                verdicts.append(whole)
            assert any(verdicts) and not all(verdicts)
        # a sweep that moves the base moves the obstacles instead, and puts them back
        assert [p.getBasePositionAndOrientation(b, physicsClientId=checker.client) for b in checker.bodies] == homes
    finally:
        checker.detach()
        checker.set_objects([])


def test_a_held_box_is_made_once_per_size_and_parked_while_not_held(wall):
    """Attaching reuses the box made for that size; a parked box changes no distance or verdict."""
    _scene, _model, graph, _, checker, _ = wall
    q1, q2 = graph.Q[graph.alive[3]], graph.Q[graph.alive[17]]
    before = (checker.distance(q1), checker.edge_collides(q1, q2))
    T = np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, 0.04], [0, 0, 0, 1.0]])
    try:
        checker.attach(np.array([0.05, 0.05, 0.08]), T)
        first = checker.attached[0]
        checker.attach(np.array([0.04, 0.04, 0.1]), T)
        other = checker.attached[0]
        checker.attach(np.array([0.05, 0.05, 0.08]), T)
        assert checker.attached[0] == first != other
    finally:
        checker.detach()
    assert checker.attached is None
    assert (checker.distance(q1), checker.edge_collides(q1, q2)) == before


def test_carrying_a_box_without_its_hold_is_refused(wall):
    """An object's size with no T_tool_obj is a clear error naming the missing hold (no box is attached)."""
    planner = _fresh_planner(wall)
    with pytest.raises(RlgpError, match="T_tool_obj"):
        planner.carrying(np.array([0.05, 0.05, 0.08]))
    assert planner.in_collision.attached is None


@pytest.mark.parametrize("scene_name", ["pick_place_pr2", "table_clearing_hsr"])
def test_joint_radii_bound_how_fast_any_point_of_the_arm_moves(scene_name):
    """The sweep's bound: per unit of an arm joint, no point of a link it moves travels further than the
    joint's radius. Checked on the corners of each link's collision bounding box (taken at home, rigid in
    the link's frame: they enclose its shapes) at random postures, by finite differences."""
    import pybullet as p

    scene = load_scene(SORTING.parent / f"{scene_name}.toml")
    model = load_robot(scene.robot.name)
    checker = WorldChecker(scene, model.manipulator().group)
    body, client = checker.robot.id, checker.client
    try:
        def frames(q):
            checker.robot.set_q(q)
            out = []
            for i in range(p.getNumJoints(body, physicsClientId=client)):
                st = p.getLinkState(body, i, computeForwardKinematics=True, physicsClientId=client)
                R = np.asarray(p.getMatrixFromQuaternion(st[5])).reshape(3, 3)
                out.append((np.asarray(st[4]), R))
            return out

        home = model.home()
        corners = {}  # link -> (8, 3) in its frame
        for i, (o, R) in enumerate(frames(home)):
            if p.getCollisionShapeData(body, i, physicsClientId=client):
                lo, hi = p.getAABB(body, i, physicsClientId=client)
                c = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
                corners[i] = (c - o) @ R
        moved = checker._moved_by
        arm = np.array(model.group(model.manipulator().group))
        rng = np.random.default_rng(7)
        lo, hi = model.limits.lower.copy(), model.limits.upper.copy()
        lo[model.limits.continuous], hi[model.limits.continuous] = -np.pi, np.pi
        eps, worst = 1e-3, 0.0  # PyBullet's link states carry ~1e-7 m of rounding
        for _ in range(15):
            q = home.copy()
            q[arm] = rng.uniform(lo[arm], hi[arm] - eps)
            at = frames(q)
            for j in arm:
                dq = q.copy()
                dq[j] += eps
                after = frames(dq)
                for i, c in corners.items():
                    if not moved[i + 1, j]:
                        continue
                    step = np.linalg.norm((c @ after[i][1].T + after[i][0]) - (c @ at[i][1].T + at[i][0]), axis=1).max()
                    worst = max(worst, step / eps / checker.radii[j])
        assert 0.3 < worst <= 1.0 + 2e-3, worst  # bounded (a lift's is exact), and not by an order of magnitude
    finally:
        checker.close()


def _exact_order(g: ReachabilityGraph) -> tuple:
    """Everything a query's result can follow, exactly: node order, each node's neighbours in order, the
    weights to the last bit and the check flags."""
    return (
        list(g.G.nodes),
        [[(int(v), g.G.edges[u, v]["weight"], g.G.edges[u, v]["checked"]) for v in g.G.adj[u]] for u in g.G.nodes],
    )


def test_a_graph_read_back_from_its_file_is_the_one_built_to_the_last_bit(tmp_path):
    """The process that builds a graph and every later one that reads its file see the same graph: the same
    node and neighbour order (networkx iterates in insertion order: Dijkstra's ties, the neighbour loops)
    and the same weights, bit for bit; so a plan does not depend on whether its graph was just built."""
    scene = load_scene(SORTING)
    params = RGParams(samples=40, seed=2)
    built, stats = load_or_build(scene, params=params, workers=1, folder=tmp_path)
    assert not stats.from_cache and built.G.number_of_edges() > built.G.number_of_nodes()
    read, stats = load_or_build(scene, params=params, workers=1, folder=tmp_path)
    assert stats.from_cache
    assert _exact_order(read) == _exact_order(built)
    # a file written in another order (an older build) is read in the same canonical order
    model = load_robot("hsr")
    meta = graph_meta(model, scene, model.manipulator().name, params)
    (path,) = tmp_path.glob("*.npz")
    with np.load(path) as z:
        arrays = dict(z)
    flip = np.random.default_rng(0).permutation(len(arrays["edges"]))
    arrays["edges"], arrays["checked"] = arrays["edges"][flip][:, ::-1], arrays["checked"][flip]
    np.savez(tmp_path / "shuffled.npz", **arrays)
    assert _exact_order(ReachabilityGraph.load(tmp_path / "shuffled.npz", model.limits, meta)) == _exact_order(built)


def test_a_graph_is_the_same_built_on_one_process_or_two():
    """The sampling jobs are seeded by job, not by process: one core (or a bench's daemonic planning child,
    which may not fork) builds the graph two cores build, so a plan does not depend on the machine."""
    scene = load_scene(SORTING)
    params = RGParams(samples=40, seed=2)
    one, _ = build_graph(scene, params=params, workers=1)
    two, _ = build_graph(scene, params=params, workers=2)
    assert _exact_order(one) == _exact_order(two)
