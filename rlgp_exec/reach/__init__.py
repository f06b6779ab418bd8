"""The reachability graph of R-LGP (section IV): node validation by whole-body IK, lazy k-NN edges,
path queries with enhancement and lazy collision checking, a solution library, persistence, pictures."""

from rlgp_exec.reach.build import BuildStats, build_graph, load_or_build, nominal_q, workspace_box
from rlgp_exec.reach.checker import CLEARANCE, WorldChecker
from rlgp_exec.reach.draw import GraphSnapshot, draw_graph_png
from rlgp_exec.reach.graph import GraphCacheError, ReachabilityGraph, RGParams
from rlgp_exec.reach.ik import IKResult, ReachIK
from rlgp_exec.reach.query import QueryStatus, ReachabilityPlanner, RGPath, interpolate

__all__ = [
    "CLEARANCE",
    "BuildStats",
    "GraphCacheError",
    "GraphSnapshot",
    "IKResult",
    "QueryStatus",
    "RGParams",
    "RGPath",
    "ReachIK",
    "ReachabilityGraph",
    "ReachabilityPlanner",
    "WorldChecker",
    "build_graph",
    "draw_graph_png",
    "interpolate",
    "load_or_build",
    "nominal_q",
    "workspace_box",
]
