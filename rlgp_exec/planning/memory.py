"""What the planners learn in one call and keep for the next: the executive's replans start from it.

The reachability graph improves at query time (nodes inserted for new targets, edges checked once or
removed because they hit a fixture). Those verdicts concern the fixtures only (objects and open
drawers are checked per query), so they hold for every later call in the same environment: a
:class:`PlannerMemory` keeps each graph, keyed like the graph cache (robot, manipulator, fixtures,
build parameters), and hands the same object to the next call. GNPP's subgraph databases are not kept:
their subgraphs include the objects' initial poses, which a replan changes.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

from rlgp_exec.reach import RGParams, load_or_build
from rlgp_exec.reach.build import BuildStats, cache_key, graph_meta
from rlgp_exec.reach.graph import ReachabilityGraph
from rlgp_exec.robot import load_robot
from rlgp_exec.scene import Scene

__all__ = ["PlannerMemory"]

log = logging.getLogger(__name__)


@dataclass
class PlannerMemory:
    """Reachability graphs by environment; ``hits`` counts calls that reused one."""

    graphs: dict[str, ReachabilityGraph] = field(default_factory=dict)
    hits: int = 0

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
