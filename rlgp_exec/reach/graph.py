"""The reachability graph (R-LGP section IV-A): nodes n(x, q, c), lazily checked k-NN edges (Eq. 3),
and its plain-file persistence (npz arrays + JSON metadata; never pickle).

A saved graph is keyed by what it depends on: the robot, the manipulator, the static scene geometry
(``scene_hash``), the joints held fixed, and the build parameters. Loading checks all of it and the
arrays themselves; anything that does not match raises :class:`GraphCacheError`, and the caller
rebuilds instead of trusting the file.
"""

from __future__ import annotations

import hashlib
import json
import logging
import zipfile
from dataclasses import asdict, dataclass
from pathlib import Path

import networkx as nx
import numpy as np
from scipy.spatial import cKDTree

from rlgp_exec.errors import RlgpError
from rlgp_exec.robot.limits import JointLimits
from rlgp_exec.robot.model import FloatArray

__all__ = ["FORMAT_VERSION", "GraphCacheError", "RGParams", "ReachabilityGraph"]

log = logging.getLogger(__name__)
FORMAT_VERSION = 1


class GraphCacheError(RlgpError):
    """A saved reachability graph that is corrupt, or built for something else."""


@dataclass(frozen=True)
class RGParams:
    """Build and query parameters. Edge cost (Eq. 3): w_x |x1 - x2| + w_q |q1 - q2| + w_c (c1 + c2)."""

    samples: int = 200
    k: int = 8  # nearest neighbours per node
    w_x: float = 1.0
    w_q: float = 0.3
    w_c: float = 10.0
    seed: int = 0
    edge_step: float = 0.01  # [m or rad] largest joint step when checking an edge for collisions
    margin_xy: float = 0.35  # [m] the sampling box extends this far beyond the fixtures
    z_above: float = 0.45  # [m] ... and this far above the highest support surface


class ReachabilityGraph:
    """Nodes (x (3,), q (nq,), c) and weighted edges; ``checked`` edges have been collision-checked."""

    def __init__(self, limits: JointLimits, plan_idx: FloatArray, params: RGParams, meta: dict) -> None:
        self.limits, self.params, self.meta = limits, params, dict(meta)
        self.plan_idx = np.asarray(plan_idx, dtype=int)
        self.X = np.zeros((0, 3))
        self.Q = np.zeros((0, limits.n))
        self.C = np.zeros(0)
        self.G = nx.Graph()
        self._tree: cKDTree | None = None
        self._tree_ids = np.zeros(0, dtype=int)

    # ------------------------------------------------------------------ nodes and edges
    def add_node(self, x: FloatArray, q: FloatArray, c: float) -> int:
        i = self.X.shape[0]
        self.X = np.vstack([self.X, np.asarray(x, float)[None]])
        self.Q = np.vstack([self.Q, np.asarray(q, float)[None]])
        self.C = np.r_[self.C, float(c)]
        self.G.add_node(i)
        self._tree = None
        return i

    def remove_node(self, i: int) -> None:
        self.G.remove_node(i)
        self._tree = None

    @property
    def alive(self) -> np.ndarray:
        return np.fromiter(self.G.nodes, dtype=int, count=self.G.number_of_nodes())

    def q_distance(self, q1: FloatArray, q2: FloatArray) -> float:
        """Joint-space distance over the planning joints (yaw the short way round)."""
        d = self.limits.difference(q2, q1)[self.plan_idx]
        return float(np.linalg.norm(d))

    def edge_cost(self, i: int, j: int) -> float:
        p = self.params
        return (
            p.w_x * float(np.linalg.norm(self.X[i] - self.X[j]))
            + p.w_q * self.q_distance(self.Q[i], self.Q[j])
            + p.w_c * (self.C[i] + self.C[j])
        )

    def edge_costs(self, i: np.ndarray, j: np.ndarray) -> FloatArray:
        """``edge_cost`` of many edges at once: node indices i, j (m,) -> (m,)."""
        p = self.params
        d_q = self.limits.difference(self.Q[j], self.Q[i])[:, self.plan_idx]
        return (
            p.w_x * np.linalg.norm(self.X[i] - self.X[j], axis=1)
            + p.w_q * np.linalg.norm(d_q, axis=1)
            + p.w_c * (self.C[i] + self.C[j])
        )

    def add_edge(self, i: int, j: int, checked: bool = False) -> None:
        self.G.add_edge(i, j, weight=self.edge_cost(i, j), checked=checked)

    def nearest(self, x: FloatArray, k: int, exclude: int | None = None) -> list[int]:
        """The ``k`` alive nodes nearest to ``x`` in task space, nearest first."""
        if self._tree is None:
            self._tree_ids = self.alive
            self._tree = cKDTree(self.X[self._tree_ids]) if self._tree_ids.size else None
        if self._tree is None:
            return []
        kk = min(k + (exclude is not None), self._tree_ids.size)
        _, idx = self._tree.query(np.asarray(x, float), k=kk)
        out = [int(self._tree_ids[i]) for i in np.atleast_1d(idx)]
        return [i for i in out if i != exclude][:k]

    def nearest_q(self, q: FloatArray, k: int, exclude: int | None = None) -> list[int]:
        """The ``k`` alive nodes nearest to configuration ``q`` (``q_distance``), nearest first."""
        ids = self.alive
        if exclude is not None:
            ids = ids[ids != exclude]
        if not ids.size:
            return []
        d = np.linalg.norm(self.limits.difference(self.Q[ids], np.asarray(q, float)[None])[:, self.plan_idx], axis=1)
        return [int(ids[i]) for i in np.argsort(d, kind="stable")[:k]]

    def connect_knn(self) -> None:
        """Connect every node to its k nearest neighbours, unchecked (lazy, as in the paper)."""
        for i in self.alive:
            for j in self.nearest(self.X[i], self.params.k, exclude=int(i)):
                if not self.G.has_edge(i, j):
                    self.add_edge(int(i), j)
        self._canonical()

    def _canonical(self) -> None:
        """The graph rebuilt with its nodes ascending and its edges in (min, max) order: networkx keeps
        insertion order, which Dijkstra's ties and every neighbour loop follow, so a graph must be in the
        same order whether it was just built or read back from its file."""
        nodes = sorted(int(i) for i in self.G.nodes)
        edges = sorted((min(u, v), max(u, v), bool(d["checked"])) for u, v, d in self.G.edges(data=True))
        u = np.array([e[0] for e in edges], dtype=int)
        v = np.array([e[1] for e in edges], dtype=int)
        weights = self.edge_costs(u, v) if edges else np.zeros(0)  # all at once, as ``load`` computes them
        G = nx.Graph()
        G.add_nodes_from(nodes)
        G.add_edges_from(
            (int(a), int(b), {"weight": float(w), "checked": e[2]})
            for a, b, w, e in zip(u, v, weights, edges, strict=True)
        )
        self.G = G
        self._tree = None

    # ------------------------------------------------------------------ persistence
    def save(self, path: str | Path) -> Path:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        alive = self.alive
        edges = np.array([(u, v) for u, v in self.G.edges], dtype=np.int64).reshape(-1, 2)
        checked = np.array([bool(self.G.edges[u, v]["checked"]) for u, v in self.G.edges], dtype=bool)
        meta = {
            **self.meta,
            "format": FORMAT_VERSION,
            "params": asdict(self.params),
            "plan_idx": self.plan_idx.tolist(),
            "joints": list(self.limits.names),
        }
        tmp = path.with_name(path.name + ".tmp.npz")
        np.savez(
            tmp,
            X=self.X,
            Q=self.Q,
            C=self.C,
            alive=alive,
            edges=edges,
            checked=checked,
            meta=np.frombuffer(json.dumps(meta, sort_keys=True).encode(), dtype=np.uint8),
        )
        tmp.replace(path)
        return path

    @classmethod
    def load(cls, path: str | Path, limits: JointLimits, expect: dict) -> ReachabilityGraph:
        """Load a saved graph; ``expect`` (robot, manipulator, scene_hash, fixed joints, params...) must
        match its metadata exactly. Raises GraphCacheError naming what is wrong."""
        path = Path(path)
        try:
            with np.load(path, allow_pickle=False) as z:
                arrays = {k: z[k] for k in ("X", "Q", "C", "alive", "edges", "checked", "meta")}
            meta = json.loads(arrays["meta"].tobytes().decode())
        except (OSError, ValueError, KeyError, UnicodeDecodeError, zipfile.BadZipFile) as e:
            raise GraphCacheError(f"{path}: not a readable reachability graph ({type(e).__name__}: {e})") from None
        if meta.get("format") != FORMAT_VERSION:
            raise GraphCacheError(f"{path}: format {meta.get('format')!r}, expected {FORMAT_VERSION}")
        for key, want in expect.items():
            if meta.get(key) != want:
                raise GraphCacheError(f"{path}: built for {key}={meta.get(key)!r}, not {want!r}")
        if meta.get("joints") != list(limits.names):
            raise GraphCacheError(f"{path}: joint names differ from the robot model's")
        X, Q, C, alive, edges, checked = (arrays[k] for k in ("X", "Q", "C", "alive", "edges", "checked"))
        n = X.shape[0]
        ok = (
            X.ndim == 2
            and X.shape[1] == 3
            and Q.shape == (n, limits.n)
            and C.shape == (n,)
            and edges.ndim == 2
            and edges.shape[1] == 2
            and checked.shape == (edges.shape[0],)
            and np.all(np.isfinite(X))
            and np.all(np.isfinite(Q))
            and np.all(np.isfinite(C))
            and np.all((alive >= 0) & (alive < n))
            and np.all(np.isin(edges, alive))
        )
        if not ok:
            raise GraphCacheError(f"{path}: arrays are inconsistent (shapes, NaN or dangling edges)")
        g = cls(limits, np.asarray(meta["plan_idx"]), RGParams(**meta["params"]), meta)
        g.X, g.Q, g.C = X.astype(float), Q.astype(float), C.astype(float)
        g.G.add_nodes_from(sorted(int(i) for i in alive))
        if len(edges):  # in (min, max) order, as ``_canonical`` leaves a built graph
            edges = np.sort(edges, axis=1)
            order = np.lexsort((edges[:, 1], edges[:, 0]))
            edges, checked = edges[order], checked[order]
        u, v = edges[:, 0].astype(int), edges[:, 1].astype(int)
        weights = g.edge_costs(u, v) if len(edges) else np.zeros(0)
        g.G.add_edges_from(
            (int(a), int(b), {"weight": float(w), "checked": bool(c)})
            for a, b, w, c in zip(u, v, weights, checked, strict=True)
        )
        return g

    def same_as(self, other: ReachabilityGraph) -> bool:
        """Same nodes, edges, weights and check flags (for round-trip tests)."""
        if not (
            np.array_equal(self.alive, other.alive)
            and np.allclose(self.X, other.X)
            and np.allclose(self.Q, other.Q)
            and np.allclose(self.C, other.C)
        ):
            return False
        e1 = {(min(u, v), max(u, v)): (round(d["weight"], 9), d["checked"]) for u, v, d in self.G.edges(data=True)}
        e2 = {(min(u, v), max(u, v)): (round(d["weight"], 9), d["checked"]) for u, v, d in other.G.edges(data=True)}
        return e1 == e2


def cache_key(meta: dict) -> str:
    return hashlib.sha256(json.dumps(meta, sort_keys=True).encode()).hexdigest()[:16]
