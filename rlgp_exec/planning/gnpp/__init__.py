"""GNPP: the Graph-NLP planner (minimal infeasible subgraphs + logic reformulation), registered as the
planners ``gnpp`` (= ``gnpp_trn``), ``gnpp_t``, ``gnpp_tr``, ``gnpp_trn``, ``gnpp_trng`` and ``oneway``."""

from __future__ import annotations

from rlgp_exec.planning.gnpp.planner import VARIANTS, GnppResult, GnppStatus, Logic, plan_gnpp
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.registry import register
from rlgp_exec.scene import Scene

__all__ = ["VARIANTS", "GnppResult", "GnppStatus", "Logic", "plan_gnpp"]


def _planner(variant: str, name: str):
    def run(scene: Scene, seed: int) -> Plan:
        from dataclasses import replace

        return replace(plan_gnpp(scene, variant).plan, planner=name)

    return run


for _v in VARIANTS:
    register(_v, _planner(_v, _v))
register("gnpp", _planner("gnpp_trn", "gnpp"))
