"""What the planners learn in one call and keep for the next: the executive's replans start from it.

The reachability graph improves at query time (nodes inserted for new targets, edges checked once or
removed because they hit a fixture). Those verdicts concern the fixtures only (objects and open
drawers are checked per query), so they hold for every later call in the same environment: a
:class:`PlannerMemory` keeps each graph, keyed like the graph cache (robot, manipulator, fixtures,
build parameters), and hands the same object to the next call.

GNPP's database of feasible and infeasible subgraphs is kept per environment too: fixtures, regions,
the objects' names and sizes, and the joints GNPP holds fixed (base, torso). Its subgraphs that rest on
an object's initial pose or an arm's initial configuration are labelled with them (see
``gnpp/database.py``), so after a replan only what still holds answers.
"""

from __future__ import annotations

import hashlib
import json
import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from rlgp_exec.reach import RGParams, load_or_build
from rlgp_exec.reach.build import BuildStats, cache_key, graph_meta
from rlgp_exec.reach.graph import ReachabilityGraph
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import Scene
from rlgp_exec.scene.randomize import scene_hash

if TYPE_CHECKING:
    from rlgp_exec.planning.gnpp.database import SubgraphDB

__all__ = ["PlannerMemory"]

log = logging.getLogger(__name__)


@dataclass
class PlannerMemory:
    """Reachability graphs and GNPP subgraph databases by environment; ``hits`` counts calls that
    reused one."""

    graphs: dict[str, ReachabilityGraph] = field(default_factory=dict)
    subgraph_dbs: dict[str, SubgraphDB] = field(default_factory=dict)
    hits: int = 0

    def subgraph_db(self, scene: Scene, q_fixed: dict[str, float]) -> SubgraphDB:
        """GNPP's database for ``scene``'s environment with the joints GNPP does not move at ``q_fixed``."""
        canon = {
            "scene": scene_hash(scene),
            "objects": sorted([o.name, [round(v, 6) for v in o.size], o.shape] for o in scene.objects),
            "fixed": {n: round(v, 4) for n, v in sorted(q_fixed.items())},
        }
        key = hashlib.sha256(json.dumps(canon, sort_keys=True).encode()).hexdigest()
        if key in self.subgraph_dbs:
            self.hits += 1
            db = self.subgraph_dbs[key]
            log.info("planner memory: the GNPP database again (%d feasible, %d infeasible subgraphs)",
                     len(db.feasible), len(db.infeasible))
            return db
        # local: the gnpp package (its planner) imports this module
        from rlgp_exec.planning.gnpp.database import SubgraphDB

        return self.subgraph_dbs.setdefault(key, SubgraphDB())

    def graph(self, scene: Scene, params: RGParams) -> tuple[ReachabilityGraph, BuildStats | None]:
        """The graph for ``scene``'s environment: the one kept from an earlier call (stats None), else
        the cached or newly built one (kept from now on)."""
        model = load_robot(scene.robot.name)
        key = cache_key(graph_meta(model, scene, model.manipulator().name, params))
        if key in self.graphs:
            self.hits += 1
            g = self.graphs[key]
            log.info("planner memory: the reachability graph again (%d nodes)", len(g.alive))
            return g, None
        g, stats = load_or_build(scene, params=params)
        self.graphs[key] = g
        return g, stats
