"""Path queries on the reachability graph (R-LGP section IV-B), with the solution library.

``query(x1, x2)``: the library answers a known pair at once, in either direction. Otherwise both
ends are inserted as nodes (IK, Eq. 2, warm-started from the nearest node) and connected to their k
nearest neighbours (lazily, like every edge: checked only when a shortest path uses it; the paper
checks them at once, which costs k edge checks per end and query); an end that cannot connect is
*enhanced*: Gaussian
samples around it, with a shrinking covariance, become intermediate nodes until one links it to the
graph. Dijkstra finds the cheapest path; its unchecked edges are checked lazily by interpolating in
configuration space (at most ``edge_step`` per joint and step) against the PyBullet world; a colliding
edge is removed and the search repeats; a node that loses all its edges is enhanced again, so the
graph stays connected. Everything learnt (new nodes, checked and removed edges) stays in the graph.
"""

from __future__ import annotations

import enum
import itertools
import logging
import math
import time
from collections.abc import Callable
from dataclasses import dataclass

import networkx as nx
import numpy as np
from scipy.spatial import cKDTree

from rlgp_exec.errors import RlgpError
from rlgp_exec.reach.checker import WorldChecker
from rlgp_exec.reach.graph import ReachabilityGraph
from rlgp_exec.reach.ik import ReachIK
from rlgp_exec.reach.ompl_plan import plan_ompl
from rlgp_exec.robot.model import FloatArray

__all__ = ["QueryStatus", "RGPath", "ReachabilityPlanner", "interpolate"]

log = logging.getLogger(__name__)
ENHANCE_SIGMAS = (0.25, 0.15, 0.08, 0.04)  # [m] the shrinking Gaussian's standard deviations
ENHANCE_TRIES = 6  # samples per sigma
MAX_REPLANS = 60  # replans after a path's edges were swept
# replans in all, those after a probe only included (~5 ms each: a shortest path and a few distance
# queries); round a table the task-space neighbours across it are cut one or two per replan
MAX_PROBED = 400
MAX_BRIDGES = 4  # component bridgings per query before the OMPL fallback
# IK solves a bridge's task-space stage may spend (~17 ms each) before it gives up: without a cap, bridges
# round table_clearing_hsr's cabinet with a cup in the hand spent up to ~500 (8.2 s) and failed, then OMPL's
# fallback found the path in 0.3-0.4 s (seed 9: 12.2 s planning)
BRIDGE_IK_SOLVES = 50
# configurations drawn per sigma round a bridge's or an enhancement's centre in joint space, before the
# task-space samples (IK): ~1 ms each (kinematics and a collision check) against ~20 ms per IK solve
Q_TRIES = 6
Q_SCALE = 2.0  # [rad per m] the yaw's and the arm joints' standard deviation per sigma of the base's


@dataclass
class _Budget:
    """IK solves left to spend (a bridge's samples share one)."""

    left: int

    def take(self) -> bool:
        """Spend one; False when none is left."""
        if self.left <= 0:
            return False
        self.left -= 1
        return True


class QueryStatus(enum.Enum):
    OK = "ok"
    START_UNREACHABLE = "start_unreachable"  # no collision-free IK for the start
    GOAL_UNREACHABLE = "goal_unreachable"
    NO_PATH = "no_path"  # the ends are nodes but no collision-free path joins them


@dataclass(frozen=True)
class RGPath:
    status: QueryStatus
    path: FloatArray  # (n, nq) configurations, start to goal; empty unless OK
    cost: float  # h, the heuristic cost (sum of edge costs); inf unless OK
    cached: bool
    query_ms: float
    reason: str = ""

    @property
    def ok(self) -> bool:
        return self.status is QueryStatus.OK


def interpolate(g: ReachabilityGraph, q1: FloatArray, q2: FloatArray, step: float) -> FloatArray:
    """Configurations (n, nq) from q1 to q2 (both included), at most ``step`` per joint apart."""
    d = g.limits.difference(q2, q1)
    n = max(1, math.ceil(float(np.abs(d).max()) / step))
    s = np.linspace(0.0, 1.0, n + 1)[:, None]
    return g.limits.wrap(q1[None] + s * d[None])


class ReachabilityPlanner:
    def __init__(self, graph: ReachabilityGraph, ik: ReachIK, checker: WorldChecker, rng_seed: int = 0) -> None:
        """``checker`` checks configurations and edges against the fixtures (PyBullet)."""
        self.g, self.ik, self.in_collision = graph, ik, checker
        self.rng = np.random.default_rng(rng_seed)
        self.library: dict[tuple, tuple[FloatArray, float]] = {}
        self.counters = {"edge_checks": 0, "edges_removed": 0, "nodes_added": 0, "enhancements": 0, "ompl_paths": 0}
        self.ompl_fallback, self.ompl_timeout = True, 3.0
        self._carry_verdicts: dict[tuple[int, int], bool] = {}
        self._estimates: dict[tuple, float] = {}

    # ------------------------------------------------------------------ the library
    @staticmethod
    def _key(x1: FloatArray, x2: FloatArray) -> tuple[tuple, bool]:
        a, b = tuple(np.round(x1, 6).tolist()), tuple(np.round(x2, 6).tolist())
        return (min(a, b), max(a, b)), a > b

    def heuristic_cost(self, x1: FloatArray, x2: FloatArray) -> float:
        """heuristicCost (Algorithm 1): h of the path, inf if there is none."""
        return self.query(x1, x2).cost

    def estimate(self, x1: FloatArray, x2: FloatArray) -> float:
        """A cheap heuristic cost: both ends snapped to their nearest nodes, Dijkstra over the graph as
        it stands (edges not yet checked count at their cost), plus the snapping distances. No IK, no
        collision checks: for ranking symbolic candidates; ``query`` certifies the chosen one."""
        key, _ = self._key(np.asarray(x1, float), np.asarray(x2, float))
        if key in self._estimates:
            return self._estimates[key]
        a, b = self.g.nearest(x1, 1), self.g.nearest(x2, 1)
        if not a or not b:
            return math.inf
        snap = self.g.params.w_x * (np.linalg.norm(self.g.X[a[0]] - x1) + np.linalg.norm(self.g.X[b[0]] - x2))
        try:
            h = nx.dijkstra_path_length(self.g.G, a[0], b[0], weight="weight") + float(snap)
        except nx.NetworkXNoPath:
            h = math.inf
        self._estimates[key] = h
        return h

    def waypoints(self, x1: FloatArray, x2: FloatArray) -> FloatArray:
        """getWaypoints (Algorithm 1): the path's configurations (n, nq); empty if there is none."""
        return self.query(x1, x2).path

    # ------------------------------------------------------------------ checks
    def edge_valid(self, i: int, j: int) -> bool:
        """Check an edge once (lazily); remember the verdict in the graph. While carrying an object, with
        objects as obstacles or a drawer out, the verdict holds for this query only (an edge too tight for
        the object may be fine for the hand), but it is split (``WorldChecker`` parts): the graph's own
        verdict (fixtures, drawers closed, self) is looked up or, with the drawers closed, checked and
        remembered, and only the rest (objects, open drawers, the held object) is checked per query."""
        checker = self.in_collision
        if checker.attached is not None or checker.world_changed:
            key = (min(i, j), max(i, j))
            if key not in self._carry_verdicts:
                self.counters["edge_checks"] += 1
                closed = all(d == 0.0 for d in checker.openings.values())
                if self.g.G.edges[i, j]["checked"]:
                    ok = not checker.edge_collides(self.g.Q[i], self.g.Q[j], part="changed")
                elif closed:
                    ok = self._graph_verdict(i, j)
                    if not ok:
                        return False  # removed from the graph: no verdict to keep for this query
                    ok = not checker.edge_collides(self.g.Q[i], self.g.Q[j], part="changed")
                else:
                    ok = not checker.edge_collides(self.g.Q[i], self.g.Q[j])
                self._carry_verdicts[key] = ok
            return self._carry_verdicts[key]
        if self.g.G.edges[i, j]["checked"]:
            return True
        self.counters["edge_checks"] += 1
        return self._graph_verdict(i, j)

    def _probe(self, i: int, j: int) -> bool:
        """A cheap look before the edge checks of a path: False when the middle of edge (i, j) comes
        within the checker's clearance of what the edge must clear (then its whole check would say so
        too, and the verdict is recorded as ``edge_valid`` records it); True otherwise, which certifies
        nothing. One distance query per part instead of a sweep: a path with a colliding edge is
        replanned without sweeping its free edges first."""
        checker = self.in_collision
        q = self.g.Q[i] + 0.5 * self.g.limits.difference(self.g.Q[j], self.g.Q[i])
        checked = self.g.G.edges[i, j]["checked"]
        if checker.attached is None and not checker.world_changed:
            if checked or checker.distance(q, "fixed", checker.clearance) >= checker.clearance:
                return True
            self.g.G.remove_edge(i, j)
            self.counters["edges_removed"] += 1
            return False
        key = (min(i, j), max(i, j))
        if key in self._carry_verdicts:
            return self._carry_verdicts[key]
        closed = all(d == 0.0 for d in checker.openings.values())
        if not checked and closed and checker.distance(q, "fixed", checker.clearance) < checker.clearance:
            self.g.G.remove_edge(i, j)
            self.counters["edges_removed"] += 1
            return False
        if checker.distance(q, "changed" if (checked or closed) else "all", checker.clearance) < checker.clearance:
            self._carry_verdicts[key] = False
            return False
        return True

    def _graph_verdict(self, i: int, j: int) -> bool:
        """The graph's verdict on an unchecked edge (fixtures, drawers closed, self-collisions): a free
        edge is marked checked, a colliding one removed."""
        if self.in_collision.edge_collides(self.g.Q[i], self.g.Q[j], part="fixed"):
            self.g.G.remove_edge(i, j)
            self.counters["edges_removed"] += 1
            return False
        self.g.G.edges[i, j]["checked"] = True
        return True

    def _weight(self, u: int, v: int, d: dict) -> float | None:
        if self._carry_verdicts.get((min(u, v), max(u, v))) is False:
            return None  # hidden for this carrying query
        return d["weight"]

    def _search_weight(self) -> str | Callable[[int, int, dict], float | None]:
        """``_weight`` for one shortest-path search, made cheap to call per edge: the attribute name
        when no edge is hidden, else a look-up in the hidden edges (both directions)."""
        hidden = [k for k, ok in self._carry_verdicts.items() if ok is False]
        if not hidden:
            return "weight"
        both = {*hidden, *((v, u) for u, v in hidden)}
        return lambda u, v, d: None if (u, v) in both else d["weight"]

    def drawers(self, openings: dict[str, float]) -> None:
        """Plan the next queries with the drawers at ``openings`` [m]: while one is out, edge verdicts
        hold for one query only (the graph remembers what holds with the drawers closed)."""
        if openings != {k: self.in_collision.openings.get(k) for k in openings}:
            self._carry_verdicts = {}
        self.in_collision.set_drawers(openings)

    def carrying(self, size: FloatArray | None, T_tool_obj: FloatArray | None = None) -> None:
        """Plan the next queries with an object of box ``size`` (3,) held at T_tool_obj (None: hand only)."""
        self._carry_verdicts = {}
        if size is None:
            self.in_collision.detach()
        elif T_tool_obj is None:
            raise RlgpError("carrying: an object of a given size needs T_tool_obj (4, 4), where the tool holds it")
        else:
            self.in_collision.attach(size, T_tool_obj)

    # ------------------------------------------------------------------ nodes
    def node_seeds(self, x: FloatArray, k: int) -> list[FloatArray]:
        """IK starts z for a hand target x: the k nearest nodes' configurations (nearest first), each
        base shifted by the node's offset from x."""
        out = []
        for j in self.g.nearest(x, k):
            z = self.ik.z_of(self.g.Q[j])
            z[:2] += np.asarray(x)[:2] - self.g.X[j][:2]
            out.append(z)
        return out

    def _solve_node(self, x: FloatArray, budget: _Budget | None = None) -> tuple[FloatArray, float] | None:
        """A collision-free configuration (q, cost) putting the tool at x, by IK from the nearest nodes and
        four base headings; ``budget``: the IK solves it may spend (none left: None)."""
        if self.ik.inside_fixture(x) is not None:
            return None
        near = self.g.nearest(x, 1)
        if near and float(np.linalg.norm(self.g.X[near[0]] - x)) < 1e-9:  # x is a node: its q is validated
            return self.g.Q[near[0]].copy(), float(self.g.C[near[0]])
        inits = self.node_seeds(x, 3)
        a0 = self.rng.uniform(-math.pi, math.pi)
        inits += [self.ik.guess(x, a0 + k * math.pi / 2) for k in range(4)]  # approach from four sides
        for z0 in inits:
            if budget is not None and not budget.take():
                return None
            res = self.ik.solve(x, z0)
            if res.ok and not self.in_collision(res.q):
                return res.q, res.cost
        return None

    def _connect(self, i: int, check: bool) -> int:
        """Edges from node i to its k nearest neighbours; with ``check``, collision-checked now (returns
        how many are valid), else left for the lazy check (returns how many were added)."""
        n = 0
        for j in self.g.nearest(self.g.X[i], self.g.params.k, exclude=i):
            if not self.g.G.has_edge(i, j):
                self.g.add_edge(i, j)
            n += self.edge_valid(i, j) if check else 1
        return n

    def _sample_q(self, q: FloatArray, sigma: float) -> tuple[FloatArray, FloatArray, float] | None:
        """A node (x, q, c) drawn round configuration q in joint space (Gaussian over the planning
        joints: ``sigma`` [m] on the base position, Q_SCALE * sigma [rad] on the rest), if it is one: in
        the limits, the base clear as IK's (``ReachIK.node_at``), collision-free; None otherwise."""
        z = np.array(q, float)
        idx = self.g.plan_idx
        scale = np.full(idx.size, Q_SCALE * sigma)
        scale[:2] = sigma
        z[idx] += self.rng.normal(0.0, 1.0, idx.size) * scale
        z = self.g.limits.wrap(z)
        node = self.ik.node_at(z)
        if node is None or self.in_collision(z):
            return None
        return node[0], z, node[1]

    def _candidates(
        self, x: FloatArray, q: FloatArray, tries: int, stage: str = "both", budget: _Budget | None = None
    ):
        """New nodes (x, q, c) round a point: first drawn in joint space round q (``_sample_q``,
        Q_TRIES per sigma; stage "q"), then task-space samples round x, each by IK (``tries`` per
        sigma; stage "ik"; ``budget``: the IK solves it may spend, shared by the caller's calls)."""
        if stage in ("q", "both"):
            for sigma in ENHANCE_SIGMAS:
                for _ in range(Q_TRIES):
                    sol = self._sample_q(q, sigma)
                    if sol is not None:
                        yield sol
        if stage in ("ik", "both"):
            for sigma in ENHANCE_SIGMAS:
                for _ in range(tries):
                    if budget is not None and budget.left <= 0:
                        return
                    xs = x + self.rng.normal(0.0, sigma, 3)
                    node = self._solve_node(xs, budget)
                    if node is not None:
                        yield xs, *node

    def _enhance(self, i: int) -> bool:
        """Samples around node i (``_candidates``), shrinking, until one connects i to the rest of the
        graph."""
        self.counters["enhancements"] += 1
        for xs, qs, cs in self._candidates(self.g.X[i], self.g.Q[i], ENHANCE_TRIES):
            j = self.g.add_node(xs, qs, cs)
            self.counters["nodes_added"] += 1
            self.g.add_edge(i, j)
            if not self.edge_valid(i, j) or self._connect(j, check=True) < 2:
                if self.g.G.degree(j) == 0:
                    self.g.remove_node(j)
                continue
            return True
        return False

    def _open(self) -> nx.Graph:
        """The graph as this query sees it: without the edges hidden for it (``_carry_verdicts``)."""
        if not any(v is False for v in self._carry_verdicts.values()):
            return self.g.G
        return nx.subgraph_view(self.g.G, filter_edge=lambda u, v: self._weight(u, v, {"weight": 0.0}) is not None)

    def _closest_pairs(self, A: np.ndarray, B: np.ndarray, pairs: int) -> list[tuple[int, int]]:
        """Up to ``pairs`` node pairs (u in A, v in B), u's nearest v in joint space (``q_distance``),
        nearest pairs first, no u twice."""
        idx = self.g.plan_idx
        QA, QB = self.g.Q[A][:, idx], self.g.Q[B][:, idx]
        cont = self.g.limits.continuous[idx]
        best = np.full(A.size, np.inf)
        arg = np.zeros(A.size, dtype=int)
        for s in range(0, B.size, 256):  # blocks of B: (|A|, 256, n) differences at most
            d = QB[None, s:s + 256] - QA[:, None]
            d[..., cont] = (d[..., cont] + np.pi) % (2 * np.pi) - np.pi
            n = np.linalg.norm(d, axis=2)
            k = n.argmin(axis=1)
            better = n[np.arange(A.size), k] < best
            best[better], arg[better] = n[np.arange(A.size), k][better], s + k[better]
        return [(int(A[k]), int(B[arg[k]])) for k in np.argsort(best, kind="stable")[:pairs]]

    def _bridge(self, a: int, b: int, pairs: int = 6) -> bool:
        """Join the components of a and b (as this query sees the graph: a component cut off only by
        edges hidden while carrying is a component of its own): samples round the midpoints of their
        closest node pairs (in joint space, then in task space), first drawn in joint space for every
        pair, then by IK (``_candidates``), become nodes with checked edges to both sides."""
        self.counters["enhancements"] += 1
        view = self._open()
        A = np.fromiter(nx.node_connected_component(view, a), dtype=int)
        B = np.fromiter(nx.node_connected_component(view, b), dtype=int)
        d, j = cKDTree(self.g.X[B]).query(self.g.X[A])
        in_task = [(int(A[k]), int(B[j[k]])) for k in np.argsort(d, kind="stable")[:pairs]]
        closest = list(dict.fromkeys(self._closest_pairs(A, B, pairs) + in_task))
        budget = _Budget(BRIDGE_IK_SOLVES)
        for stage in ("q", "ik"):
            for u, v in closest:
                mid = 0.5 * (self.g.X[u] + self.g.X[v])
                q_mid = self.g.Q[u] + 0.5 * self.g.limits.difference(self.g.Q[v], self.g.Q[u])
                for xs, qs, cs in self._candidates(mid, q_mid, 2, stage, budget):
                    n = self.g.add_node(xs, qs, cs)
                    self.g.add_edge(u, n)
                    self.g.add_edge(n, v)
                    if self.edge_valid(u, n) and self.edge_valid(n, v):
                        self.counters["nodes_added"] += 1
                        self._connect(n, check=False)
                        return True
                    self.g.remove_node(n)
        return False

    def insert(self, x: FloatArray, q: FloatArray | None = None) -> int | None:
        """A node at x (with q, or by IK), connected to the graph; None if x has no valid configuration.
        A target that is already a node (same x, no q given) is that node."""
        given = q is not None
        if q is None:
            near = self.g.nearest(x, 1)
            if near and float(np.linalg.norm(self.g.X[near[0]] - np.asarray(x, float))) < 1e-9:
                return near[0]
            sol = self._solve_node(np.asarray(x, float))
            if sol is None:
                return None
            q, c = sol
        else:
            if self.in_collision(q):
                return None
            c = 0.0
        i = self.g.add_node(x, q, c)
        self.counters["nodes_added"] += 1
        self._connect(i, check=False)  # lazily: Dijkstra's path is checked, and a node cut off is enhanced
        if given:  # a configuration of its own (the robot's, a keyframe's): its neighbours in joint space too
            for j in self.g.nearest_q(q, self.g.params.k, exclude=i):
                if not self.g.G.has_edge(i, j):
                    self.g.add_edge(i, j)
        return i

    # ------------------------------------------------------------------ queries
    def query(
        self, x1: FloatArray, x2: FloatArray, q1: FloatArray | None = None, q2: FloatArray | None = None
    ) -> RGPath:
        """The cheapest collision-free path from x1 to x2; either end may come with its configuration
        (the robot's current one, an optimised keyframe), which the path then starts or ends at."""
        t0 = time.perf_counter()
        x1, x2 = np.asarray(x1, float), np.asarray(x2, float)
        key, flipped = self._key(x1, x2)
        if q1 is None and q2 is None and key in self.library:
            path, cost = self.library[key]
            return RGPath(QueryStatus.OK, path[::-1] if flipped else path, cost, True, (time.perf_counter() - t0) * 1e3)
        if q1 is not None and q2 is not None and not self.in_collision.edge_collides(q1, q2):
            # both ends given and the straight motion between them is free: nothing to search
            self.counters["edge_checks"] += 1
            path = np.array([q1, q2])
            return RGPath(
                QueryStatus.OK,
                path,
                self.g.q_distance(q1, q2) * self.g.params.w_q,
                False,
                (time.perf_counter() - t0) * 1e3,
                "direct",
            )
        a = self.insert(x1, q1)
        if a is None:
            return RGPath(
                QueryStatus.START_UNREACHABLE,
                np.zeros((0, self.g.limits.n)),
                math.inf,
                False,
                (time.perf_counter() - t0) * 1e3,
                f"no collision-free configuration reaches {x1.round(3)}",
            )
        b = self.insert(x2, q2)
        if b is None:
            return RGPath(
                QueryStatus.GOAL_UNREACHABLE,
                np.zeros((0, self.g.limits.n)),
                math.inf,
                False,
                (time.perf_counter() - t0) * 1e3,
                f"no collision-free configuration reaches {x2.round(3)}",
            )
        bridges, swept = 0, 0
        for _ in range(MAX_PROBED):
            if swept >= MAX_REPLANS:
                break
            try:
                nodes = nx.dijkstra_path(self.g.G, a, b, weight=self._search_weight())
            except nx.NetworkXNoPath:
                bridges += 1
                if bridges > MAX_BRIDGES or not self._bridge(a, b):
                    break
                continue
            bad = [(u, v) for u, v in itertools.pairwise(nodes) if not self._probe(u, v)]
            if not bad:  # no edge's middle collides: check them all (a free edge costs a whole sweep)
                swept += 1
                bad = [(u, v) for u, v in itertools.pairwise(nodes) if not self.edge_valid(u, v)]
            if not bad:
                path = self.g.Q[nodes]
                cost = float(sum(self.g.G.edges[u, v]["weight"] for u, v in itertools.pairwise(nodes)))
                if q1 is None and q2 is None:
                    self.library[key] = (path[::-1] if flipped else path, cost)
                return RGPath(QueryStatus.OK, path, cost, False, (time.perf_counter() - t0) * 1e3)
            for u, v in bad:
                for n in (u, v):
                    if n in self.g.G and self.g.G.degree(n) == 0:
                        self._enhance(n)
        if self.ompl_fallback:  # the graph cannot certify a path: plan this segment with OMPL

            X = self.g.X[self.g.alive]
            ompl_path = plan_ompl(
                self.in_collision,
                self.g.plan_idx,
                self.g.Q[a],
                self.g.Q[b],
                X[:, :2].min(axis=0) - 1.0,
                X[:, :2].max(axis=0) + 1.0,
                timeout=self.ompl_timeout,
            )
            if ompl_path is not None:
                cost = float(sum(self.g.q_distance(u, v) for u, v in itertools.pairwise(ompl_path)))
                self.counters["ompl_paths"] += 1
                return RGPath(QueryStatus.OK, ompl_path, cost, False, (time.perf_counter() - t0) * 1e3, "ompl")
        return RGPath(
            QueryStatus.NO_PATH,
            np.zeros((0, self.g.limits.n)),
            math.inf,
            False,
            (time.perf_counter() - t0) * 1e3,
            "no collision-free path after replanning",
        )


def _bisection_order(n: int) -> list[int]:
    """Indices 0..n-1, the ends first, then midpoints of ever finer halves (finds collisions early)."""
    order, seen = [0, n - 1], {0, n - 1}
    queue = [(0, n - 1)]
    while queue:
        lo, hi = queue.pop(0)
        if hi - lo < 2:
            continue
        mid = (lo + hi) // 2
        if mid not in seen:
            seen.add(mid)
            order.append(mid)
        queue += [(lo, mid), (mid, hi)]
    return [i for i in order if 0 <= i < n]
