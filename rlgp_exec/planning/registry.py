"""The planners by name: one entry point (``plan``) that every caller uses — the ``plan`` and ``bench``
commands, the executive and the daemon — so a planner is added in one place.

Each planner takes a scene (with its goal), a seed, an optional :class:`PlannerMemory` (what earlier
calls learnt; the executive keeps one across replans) and its :class:`PlanLimits` (CPU-time budget, search
expansions), and returns a validated ``Plan``.
"""

from __future__ import annotations

from collections.abc import Callable

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.blas import single_blas_thread
from rlgp_exec.planning.limits import DEFAULT_LIMITS, PlanLimits
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.plan import Plan
from rlgp_exec.scene import Scene

__all__ = ["PLANNERS", "plan", "planner_names", "register"]

PlannerFn = Callable[[Scene, int, PlannerMemory | None, PlanLimits], Plan]


def _rlgp(name: str) -> PlannerFn:
    def run(scene: Scene, seed: int, memory: PlannerMemory | None = None, limits: PlanLimits = DEFAULT_LIMITS) -> Plan:
        # local: R-LGP's planner loads on its first plan, as GNPP's below
        from rlgp_exec.planning.rlgp import TIME_BUDGET_S, plan_scene

        kw: dict[str, float | int] = {"time_budget_s": limits.time_budget_s or TIME_BUDGET_S}
        if limits.max_expansions is not None:
            kw["max_expansions"] = limits.max_expansions
        return plan_scene(scene, name, seed=seed, memory=memory, **kw)  # type: ignore[arg-type]

    return run


PLANNERS: dict[str, PlannerFn] = {
    "rlgp": _rlgp("rlgp"),  # reachability-graph heuristic cost and guided paths
    "lgp": _rlgp("lgp"),  # distance-only heuristic (the RHH-LGP stand-in)
}


def register(name: str, fn: PlannerFn) -> None:
    """Add a planner under ``name`` (later registrations replace earlier ones)."""
    PLANNERS[name] = fn


_loaded: list[bool] = []


def _load_plugins() -> None:
    """GNPP's variants, imported on first use (its package loads Fast Downward's wrapper and the NLPs)."""
    if _loaded:
        return
    # local: GNPP's package (Fast Downward's wrapper, its NLPs) loads on first use
    from rlgp_exec.planning.gnpp import PLANNERS as GNPP_PLANNERS

    for name, fn in GNPP_PLANNERS.items():
        PLANNERS.setdefault(name, fn)  # a planner registered under the same name stays
    _loaded.append(True)


def planner_names() -> list[str]:
    _load_plugins()
    return list(PLANNERS)


def plan(
    scene: Scene, planner: str = "rlgp", seed: int = 0, memory: PlannerMemory | None = None,
    limits: PlanLimits = DEFAULT_LIMITS,
) -> Plan:
    """Plan ``scene``'s goal with ``planner`` within ``limits``; raises RlgpError naming the valid planners
    if unknown. Every BLAS copy runs one thread while it plans (``planning.blas``)."""
    _load_plugins()
    if planner not in PLANNERS:
        raise RlgpError(f"unknown planner {planner!r}; valid: {list(PLANNERS)}")
    single_blas_thread()
    return PLANNERS[planner](scene, seed, memory, limits)
