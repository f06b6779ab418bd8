"""The Graph-NLP planner (GNPP paper, Fig. 3) and its ablations.

Loop: a logic plan for the current (reformulated) task -> its graph-NLP -> a small infeasible
subgraph (``conflicts``) or a solution -> forbid the conflict's partial-state sequence in the logic
task (``symbolic.reformulate``, the paper's compilation; the sequence generalised along the objects'
``Equal`` chains first, ``graph.generalise``) -> again. A solution is laid out as joint
paths and replayed (``validate_plan``); a replay failure forbids that whole state sequence.

Variants (paper Sec. VIII-C): ``gnpp_t`` (time search on the full graph: conflicts are whole state
windows), ``gnpp_tr`` (+ relaxations), ``gnpp_trn`` (+ convergence heuristic and QuickXplain:
minimal conflicts), ``gnpp_trng`` (+ database of feasible/infeasible subgraphs), and ``oneway``
(solve the full graph, block the whole plan on failure).
"""

from __future__ import annotations

import dataclasses
import enum
import logging
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.actions import GNPP_ACTIONS, Kind, ground_text
from rlgp_exec.planning.budget import MEMORY_CAP_BYTES, Budget, BudgetError, cpu_clock, using
from rlgp_exec.planning.capabilities import refuse, start_reach_gaps
from rlgp_exec.planning.gnpp.conflicts import (
    FILTER_MAX,
    FILTER_MAX_NO_ROBOT,
    Checker,
    Conflict,
    ExtractOptions,
    find_conflict,
)
from rlgp_exec.planning.gnpp.database import SubgraphDB
from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.graph import generalise, to_forbidden, variables
from rlgp_exec.planning.gnpp.guess import TopIK, ik_seed, initial_guess
from rlgp_exec.planning.gnpp.motion import phases_of
from rlgp_exec.planning.gnpp.pntc import Var, add_flags, add_moves, factors_of
from rlgp_exec.planning.gnpp.priors import reach_priors
from rlgp_exec.planning.gnpp.repair import repair_rounds
from rlgp_exec.planning.gnpp.solver import LM_MAX_FACTORS, GraphSolver, SolverRun
from rlgp_exec.planning.gnpp.trajectory import Trajectories
from rlgp_exec.planning.memory import PlannerMemory
from rlgp_exec.planning.plan import Plan
from rlgp_exec.planning.symbolic import (
    FDStatus,
    ForbiddenSequence,
    GroundAction,
    GroundProblem,
    PartialState,
    best_first,
    goal_lower_bound,
    ground_scene,
    reformulate,
    solve_ground,
    without_detours,
)
from rlgp_exec.planning.validate import validate_with_fallbacks
from rlgp_exec.robot import load_robot
from rlgp_exec.robot.model import FloatArray
from rlgp_exec.scene import Scene

__all__ = ["LOGIC_MAX_EXPANSIONS", "VARIANTS", "GnppResult", "GnppStatus", "Logic", "plan_gnpp"]

log = logging.getLogger(__name__)

VARIANTS: dict[str, ExtractOptions | None] = {
    "gnpp_t": ExtractOptions(time_search=True, relaxations=False, convergence=False),
    "gnpp_tr": ExtractOptions(time_search=True, relaxations=True, convergence=False),
    "gnpp_trn": ExtractOptions(time_search=True, relaxations=True, convergence=True),
    "gnpp_trng": ExtractOptions(time_search=True, relaxations=True, convergence=True, database=True),
    "oneway": None,
}
#: the actions the graph-NLP has factors for; the task's others (pick_from_drawer) are left out of its logic
GEOMETRIC = GNPP_ACTIONS


class Logic(enum.Enum):
    #: A* with hmax (admissible, and it has conditional effects) on the ground, reformulated task: shortest
    #: plans first, as the internal search and the paper's N. lama-first (satisficing) returns plans with
    #: detours, each one more graph-NLP to refute, and is many times slower on the towers
    FAST_DOWNWARD = "fd"
    INTERNAL = "internal"  # our best-first search on the same compiled task


class GnppStatus(enum.Enum):
    SOLVED = "solved"
    INFEASIBLE = "infeasible"  # no logic plan avoids the learnt conflicts (and blocked plans, see the reason)
    TIMEOUT = "timeout"
    LOGIC_FAILED = "logic_failed"  # the logic planner ended without a proof (budget, error)


@dataclass(frozen=True)
class GnppResult:
    status: GnppStatus
    plan: Plan
    conflicts: tuple[ForbiddenSequence, ...]
    conflict_factors: tuple[Conflict, ...]
    n0: int | None  # length of the first logic plan
    iterations: int
    logic_time_s: float
    counters: dict = field(default_factory=dict)


LOGIC_MAX_EXPANSIONS = 200_000  # the internal logic search's expansions per iteration


def _logic_plan(
    task: GroundProblem, forbidden: list[ForbiddenSequence], logic: Logic, timeout_s: float,
    max_expansions: int = LOGIC_MAX_EXPANSIONS,
) -> tuple[tuple[GroundAction, ...] | None, GnppStatus | None, str]:
    ref = reformulate(task, forbidden).problem
    if logic is Logic.FAST_DOWNWARD:
        r = solve_ground(ref, search="optimal", timeout_s=max(timeout_s, 1.0))
        if r.solved:
            return r.plan, None, ""
        if r.status is FDStatus.UNSOLVABLE:
            return None, GnppStatus.INFEASIBLE, "Fast Downward: unsolvable"
        return None, GnppStatus.LOGIC_FAILED, f"Fast Downward: {r.status.value}: {r.reason}"
    search = best_first(ref, max_expansions=max_expansions, heuristic=goal_lower_bound(task), max_visits=1)
    for cand in search:
        return cand.actions, None, ""
    if search.stats.exhausted:
        return None, GnppStatus.INFEASIBLE, "best-first search: no plan left"
    return None, GnppStatus.LOGIC_FAILED, "best-first search: expansion budget hit"


def plan_gnpp(
    scene: Scene,
    variant: str = "gnpp_trn",
    logic: Logic = Logic.INTERNAL,
    timeout_s: float = 60.0,
    max_iterations: int = 300,
    memory: PlannerMemory | None = None,
    trajectories: bool = True,
    on_nlp: Callable[[SolverRun], None] | None = None,
    lm_verdicts: bool = False,
    memory_cap_bytes: int = MEMORY_CAP_BYTES,
    max_expansions: int = LOGIC_MAX_EXPANSIONS,
    drive_base: bool | None = None,
) -> GnppResult:
    """Plan the scene's goal with a GNPP variant (see ``VARIANTS``); with ``memory``, the subgraph
    database (variants with one) is the one earlier calls in this environment filled. ``timeout_s``
    is CPU time (``cpu_clock``: this process and Fast Downward), the paper's measure: the same
    budget on a loaded machine takes longer, not fewer NLPs. ``trajectories``: each arm's moves of a
    solved plan optimised as 20 waypoints (``gnpp.trajectory``), else its straight motions. ``on_nlp``:
    called after every graph-NLP run of IPOPT (``GraphSolver.observer``). ``lm_verdicts``: the search's small
    arm NLPs answered by Levenberg-Marquardt (``solver.LM_MAX_FACTORS``: measured, not the default), else
    IPOPT answers every NLP of the search (``refute``'s checks of a fixed-base arm's conflicts are LM's either way:
    ``GraphSolver.lm_refute``). A plan whose replay fails is laid out once more from its graph-NLP point moved
    inside its inequality rows (``GraphSolver.polish``) before it is blocked. The budget (``timeout_s``, and
    ``memory_cap_bytes`` of growth, ``planning.budget``) is checked inside every stage; once spent, the
    status is TIMEOUT with a reason "budget: ..." naming the stage and iteration. ``max_expansions``: the
    internal logic search's expansion cap per iteration (Fast Downward has its own). ``drive_base``: the base
    moves (the paper's start-move / end-move), or stays at the start; None: ``FactorLib.mobile``'s rule."""
    if variant not in VARIANTS:
        raise RlgpError(f"unknown GNPP variant {variant!r}; valid: {list(VARIANTS)}")
    refuse(scene, variant)  # TaskRefusedError before any search: what GNPP or the robot cannot do
    t0 = time.perf_counter()
    b = Budget(timeout_s, memory_cap_bytes)
    with using(b):
        try:
            return _plan(
                scene, variant, logic, max_iterations, memory, trajectories, on_nlp, lm_verdicts, b, max_expansions,
                drive_base,
            )
        except BudgetError as e:  # in the set-up (the loop returns its own)
            log.info("%s: %s", variant, e)
            plan = Plan(False, variant, (), np.zeros((0, 0)), (), time.perf_counter() - t0, 0, 0, None, str(e))
            return GnppResult(GnppStatus.TIMEOUT, plan, (), (), None, 0, 0.0, {"cpu_s": b.spent()})


def _plan(
    scene: Scene,
    variant: str,
    logic: Logic,
    max_iterations: int,
    memory: PlannerMemory | None,
    trajectories: bool,
    on_nlp: Callable[[SolverRun], None] | None,
    lm_verdicts: bool,
    budget: Budget,
    max_expansions: int = LOGIC_MAX_EXPANSIONS,
    drive_base: bool | None = None,
) -> GnppResult:
    """``plan_gnpp`` under its open ``budget``."""
    opts = VARIANTS[variant]
    t0, c0 = time.perf_counter(), budget.start
    model = load_robot(scene.robot.name)
    lib = FactorLib(model, scene, drive_base)
    gaps = start_reach_gaps(scene)
    if lib.mobile and lib.riders:
        log.info("%s: the base moves (its arms share it): %s", scene.name, "; ".join(map(str, gaps)) or "asked")
    ik, solver = TopIK(lib), GraphSolver(lib)
    solver.observer = on_nlp
    if lm_verdicts:
        solver.lm_max_factors = LM_MAX_FACTORS
    traj = Trajectories(lib) if trajectories else None
    if lib.mobile:
        solver.seeder = lambda factors, guess, bearing=0: ik_seed(lib, ik, factors, guess, bearing)
    db = None
    if opts is not None and opts.database:
        arm_idx = {int(i) for m in lib.arms for i in lib.arm_index(m)}
        fixed = {n: float(lib.q_nominal[i]) for i, n in enumerate(model.joint_names) if i not in arm_idx}
        db = SubgraphDB() if memory is None else memory.subgraph_db(scene, fixed)
        db.bind(lib.call_context())
    mobile = (lib.base_arm,) if lib.mobile else ()
    task = add_flags(add_moves(without_detours(ground_scene(scene, manipulators=list(lib.arms))), mobile, lib.riders))
    task = dataclasses.replace(task, operators=tuple(op for op in task.operators if op.action.name in GEOMETRIC))
    wide = lib.too_wide()
    if wide:  # no pick of them: a plan that needs one ends "infeasible", with this reason
        ops = tuple(op for op in task.operators if not (op.action.name == Kind.PICK and op.action.args[1] in wide))
        task = dataclasses.replace(task, operators=ops)
        log.warning("%s: wider than the open gripper, not picked: %s", scene.name, wide)
    objects = [o.name for o in scene.objects]
    priors = reach_priors(gaps, lib.arms, lib.base_arm, lib.riders, task.init) if lib.mobile else []
    if priors:
        log.info("%s: %d conflicts from the arms' reach of the start base: %s", scene.name, len(priors),
                 "; ".join(sorted({str(g) for _, g in priors})))
    forbidden: list[ForbiddenSequence] = [f for f, _ in priors]
    found: list[Conflict] = []
    n0, logic_s, blocked_plans, refuted = None, 0.0, 0, 0
    reasons: list[str] = []

    def result(status: GnppStatus, reason: str, plan: Plan | None = None, it: int = 0) -> GnppResult:
        counters = {
            "n0": n0,
            "n": len(plan.actions) if plan is not None and plan.success else None,
            "nlp": solver.n_solves,
            "db_hits": db.hits if db is not None else 0,
            "conflicts": len(found),
            "blocked_plans": blocked_plans,
            "refuted": refuted,
            "iterations": it,
            "logic_s": logic_s,
            "nlp_s": solver.solve_time_s,
            "cpu_s": cpu_clock() - c0,  # CPU time, Fast Downward's included (the budget's clock)
        }
        if plan is None:
            plan = Plan(
                False,
                variant,
                (),
                np.zeros((0, model.nq)),
                (),
                time.perf_counter() - t0,
                solver.n_solves,
                0,
                None,
                reason,
            )
        plan = replace(plan, planning_time_s=time.perf_counter() - t0, counters=counters)
        return GnppResult(status, plan, tuple(forbidden), tuple(found), n0, it, logic_s, counters)

    if gaps and not lib.mobile:
        return result(GnppStatus.INFEASIBLE, f"infeasible: the {scene.robot.name}'s base is kept at its start "
                      "(drive_base=False), where no arm reaches: " + "; ".join(map(str, gaps)))

    for it in range(1, max_iterations + 1):
        budget.scope, budget.stage = f"iteration {it}", "logic plan"
        try:
            budget.check()
            tl = time.perf_counter()
            actions, status, why = _logic_plan(task, forbidden, logic, budget.left(), max_expansions)
            logic_s += time.perf_counter() - tl
            if actions is None:
                assert status is not None
                proof = ""
                if status is GnppStatus.INFEASIBLE:
                    proof = f" (every logic plan contains one of {len(found)} learnt conflicts"
                    if priors:
                        proof += f" or of {len(priors)} from the reach of the start base"
                    if blocked_plans:  # not a proof: a whole plan is blocked after a solver, layout or replay failure
                        proof += f" or is one of {blocked_plans} plans blocked after failing, which proves nothing"
                    proof += ")"
                    if not lib.mobile:  # the likeliest cause on a fixed base, which the reach bound let through
                        proof += (f"; the {scene.robot.name}'s base stays at its start here, so a conflict may be an "
                                  "object or target its arms cannot reach from there (rlgp drives the base)")
                    if wide:
                        proof += "; not picked, wider than the open gripper ({:.3f} m inside): {}".format(
                            2 * lib.finger_inner, ", ".join(f"{o} {w:.3f} m" for o, w in sorted(wide.items()))
                        )
                return result(status, f"{status.value}: {why}{proof}", it=it)
            if n0 is None:
                n0 = len(actions)
            log.info("%s iteration %d: %s (%d NLPs solved, %d conflicts learnt so far)", variant, it,
                     " ".join(map(str, actions)), solver.n_solves, len(found))
            bad = [a for a in actions if a.name not in GEOMETRIC]
            states = task.simulate(actions)
            if bad:
                forbidden.append(_whole(states))
                reasons.append(f"{bad[0]}: no geometry for {bad[0].name}")
                continue
            budget.stage = "initial guess"
            graph = factors_of(states, lib.arms, objects, mobile, lib.riders)
            guess = initial_guess(lib, ik, states, variables(graph))
            check = Checker(solver, guess, db)
            values: dict | None  # the graph-NLP's solution (None: every conflict found was refuted)
            budget.stage = "graph-NLP"
            if opts is None:  # one-way: the full graph, the whole plan blocked on failure
                if not check.feasible(graph):
                    forbidden.append(_whole(states))
                    blocked_plans += 1
                    continue
                conflict, values = None, (dict(check.last.values) if check.last else {})
            else:
                conflict, values, n_refuted = _checked_conflict(check, graph, opts)
                refuted += n_refuted
            if conflict is not None:
                found.append(conflict)
                forbidden.append(to_forbidden(generalise(conflict.factors)))
                log.info("%s iteration %d: learnt %s, from the infeasible subgraph %s", variant, it, forbidden[-1],
                         conflict)
                continue
            if values is None:  # every conflict found was refuted: no proof either way, block this plan
                forbidden.append(_whole(states))
                blocked_plans += 1
                reasons.append("conflicts refuted by other starts, or too large to check")
                continue
            budget.stage = "layout and replay"
            laid = _realise(scene, lib, ik, traj, variant, actions, values, t0, solver.n_solves)
            if isinstance(laid, Plan) and not laid.success:
                polished = solver.polish(graph, values)
                if polished is not values:  # once more, the keyframes off their clearance bounds
                    log.info("%s iteration %d: replay failed (%s); again from a polished point", variant, it,
                             laid.reason)
                    again = _realise(scene, lib, ik, traj, variant, actions, polished, t0, solver.n_solves)
                    laid = again if isinstance(again, Plan) else laid
            if isinstance(laid, str):
                log.info("%s iteration %d: no layout: %s", variant, it, laid)
                forbidden.append(_whole(states))
                blocked_plans += 1
                reasons.append(laid)
                continue
            plan = laid
            if plan.success:
                return result(GnppStatus.SOLVED, "ok", plan, it)
            log.info("%s iteration %d: replay failed: %s", variant, it, plan.reason)
            reasons.append(f"replay: {plan.reason}")
            forbidden.append(_whole(states))
            blocked_plans += 1
        except BudgetError as e:
            why = f" ({'; '.join(reasons[-2:])})" if reasons else ""
            return result(GnppStatus.TIMEOUT, f"{e}{why}", it=it)
    return result(GnppStatus.TIMEOUT, f"no plan in {max_iterations} iterations ({'; '.join(reasons[-2:])})")


def _realise(
    scene: Scene,
    lib: FactorLib,
    ik: TopIK,
    traj: Trajectories | None,
    variant: str,
    actions: tuple[GroundAction, ...],
    values: Mapping[Var, FloatArray],
    t0: float,
    n_solves: int,
) -> Plan | str:
    """The plan of the graph-NLP's solution ``values``: its motions laid out (``phases_of``), trajectories
    optimised (``traj``), replayed (``validate_with_fallbacks``), moves that collide there planned again
    (``repair_transits``) and replayed once more; or why no motion was found."""
    laid = phases_of(lib, ik, actions, values)
    if isinstance(laid, str):
        return laid
    straight, keyframes, transits = laid
    phases, fallbacks = traj.optimise(straight, transits) if traj is not None else (list(straight), {})
    validation, phases, kept = validate_with_fallbacks(scene, phases, fallbacks)
    if traj is not None:
        traj.kept(len(fallbacks) - len(kept), validation.ok and bool(kept))
    if not validation.collision_free:
        validation, phases, kept = repair_rounds(scene, lib, phases, transits, validation, fallbacks, kept, variant)
    return Plan(
        validation.ok,
        variant,
        tuple(ground_text(a.name, a.args, len(lib.arms) > 1) for a in actions),
        keyframes,
        tuple(phases),
        time.perf_counter() - t0,
        n_solves,
        0,
        validation,
        "ok" if validation.ok else "; ".join([*validation.collisions[:3], *validation.unmet]),
        level3=None if traj is None else traj.stats,
    )


def _checked_conflict(
    check: Checker, graph: list, opts: ExtractOptions, retries: int = 2
) -> tuple[Conflict | None, dict | None, int]:
    """``find_conflict``, with each conflict checked from other starts before it is believed (a local
    solver's failure is no proof). A refuted conflict's feasible point joins the guess (and corrects
    the database) and the search runs again, up to ``retries`` times. Returns (conflict, None, n) or
    (None, the full graph's solution, n) or (None, None, n) when every conflict found was refuted."""
    for k in range(retries + 1):
        conflict, values = find_conflict(check, graph, opts)
        if conflict is None:
            return None, values, k
        cap = FILTER_MAX if any(f.robot for f in conflict.factors) else FILTER_MAX_NO_ROBOT
        if opts.convergence and len(conflict.factors) > cap:
            # not cut down to a minimal one (too large): checking it from other starts costs several of
            # the slowest solves, and it forbids little more than this plan; the plan is blocked
            # instead (no proof claimed: a blocked plan is counted apart from learnt conflicts)
            log.info("conflict of %d factors not minimised: the plan is blocked", len(conflict.factors))
            return None, None, k
        point = check.solver.refute(conflict.factors, check.guess, seed=k)
        if point is None:
            return conflict, None, k
        log.info("conflict refuted by another start: %s", conflict)
        check.guess.update(point)
        check.forget_infeasible()
        check.proven_feasible(conflict.factors, point)
        if check.db is not None:
            check.db.correct(conflict.factors)
    return None, None, retries + 1


def _whole(states) -> ForbiddenSequence:
    """The complete state sequence of a plan (blocks that plan)."""
    return ForbiddenSequence(tuple(PartialState(frozenset(s)) for s in states))
