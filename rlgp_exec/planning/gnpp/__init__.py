"""GNPP: the Graph-NLP planner (minimal infeasible subgraphs + logic reformulation), registered as the
planners ``gnpp`` (= ``gnpp_trn``), ``gnpp_t``, ``gnpp_tr``, ``gnpp_trn``, ``gnpp_trng`` and ``oneway`` (logic by
the internal best-first search on the compiled task), ``gnpp_trn_fd`` (logic by Fast Downward) and ``gnpp_trn_lm``
(the search's small arm NLPs answered by Levenberg-Marquardt: ``solver.LM_MAX_FACTORS``)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from rlgp_exec.planning.gnpp.planner import LOGIC_MAX_EXPANSIONS, VARIANTS, GnppResult, GnppStatus, Logic, plan_gnpp
from rlgp_exec.planning.limits import DEFAULT_LIMITS, PlanLimits
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.plan import Plan
from rlgp_exec.scene import Scene

BENCH_TIMEOUT_S = 100.0  # [s] CPU per planning call of a registered variant (the paper's timeout: 100 s)

__all__ = ["BENCH_TIMEOUT_S", "PLANNERS", "VARIANTS", "GnppResult", "GnppStatus", "Logic", "plan_gnpp"]


def _planner(variant: str, name: str, logic: Logic = Logic.INTERNAL, lm_verdicts: bool = False):
    def run(scene: Scene, seed: int, memory: PlannerMemory | None = None, limits: PlanLimits = DEFAULT_LIMITS) -> Plan:

        if not scene.start.empty:  # its PNTC model starts from empty grippers and closed drawers
            why = f"holding {scene.start.held!r}" if scene.start.held else f"drawers out {dict(scene.start.openings)}"
            return Plan(False, name, (), np.zeros((0, 0)), (), 0.0, 0, 0, None,
                        f"unsupported start: {why}; {name} plans from empty hands and closed drawers (use rlgp)")
        res = plan_gnpp(
            scene, variant, logic=logic, timeout_s=limits.time_budget_s or BENCH_TIMEOUT_S, memory=memory,
            lm_verdicts=lm_verdicts, max_expansions=limits.max_expansions or LOGIC_MAX_EXPANSIONS,
        )
        return replace(res.plan, planner=name)

    return run


#: GNPP's planners by name, as ``planning.registry`` lists them
PLANNERS = {v: _planner(v, v) for v in VARIANTS}
PLANNERS["gnpp"] = _planner("gnpp_trn", "gnpp")
PLANNERS["gnpp_trn_fd"] = _planner("gnpp_trn", "gnpp_trn_fd", Logic.FAST_DOWNWARD)  # the same, logic by Fast Downward
PLANNERS["gnpp_trn_lm"] = _planner("gnpp_trn", "gnpp_trn_lm", lm_verdicts=True)  # the same, LM verdicts
