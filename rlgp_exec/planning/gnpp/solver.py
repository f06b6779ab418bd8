"""Feasibility of a (sub)graph-NLP: assemble its factors into one sparse CasADi NLP and solve it with
IPOPT (or, optionally, Levenberg-Marquardt on small arm NLPs: ``LM_MAX_FACTORS``), returning the
convergence point and every factor's violation there (Def. 4.3).

The NLP is ``min 1e-3 |x - x_guess|^2  s.t.  lower <= h(x) <= upper, variable bounds``; it is built
once per *structure* (factor keys and the pattern of shared variables, time shifts ignored) and
cached, so the many small subgraphs GNPP solves reuse their solvers. Its rows and their Jacobian are
put together from each factor key's cached function and Jacobian (``gnpp.assembly``).
"""

from __future__ import annotations

import enum
import logging
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass

import casadi as ca
import numpy as np

from rlgp_exec.casadi_call import BufferedFunction
from rlgp_exec.ipopt import LEAN
from rlgp_exec.planning import budget
from rlgp_exec.planning.gnpp.assembly import assemble
from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.graph import canonical, variables
from rlgp_exec.planning.gnpp.lm import LevenbergMarquardt
from rlgp_exec.planning.gnpp.pntc import Factor, Var
from rlgp_exec.planning.gnpp.presolve import Presolved, presolve
from rlgp_exec.planning.margins import FEAS_TOL
from rlgp_exec.robot.model import FloatArray

__all__ = [
    "CLEAR_GAP",
    "FEAS_TOL",
    "LM_MAX_FACTORS",
    "OBJECT_STARTS",
    "RESTART_ABOVE",
    "SEARCH",
    "Feasibility",
    "GraphSolver",
    "SolveResult",
    "SolverRun",
    "ipopt_options",
    "run_feasible",
]

log = logging.getLogger(__name__)
W_REG = 1e-3
X_JITTER = np.array([0.06, 0.06, 0.01, 0.6])  # [m, m, m, rad] std of an object start's perturbation
IPOPT = {
    "ipopt.print_level": 0,
    "print_time": False,
    "ipopt.sb": "yes",
    "ipopt.tol": 1e-6,
    "ipopt.constr_viol_tol": 1e-5,
    # feasibility is all that is asked: stop at the first iterate that satisfies the constraints
    "ipopt.acceptable_iter": 1,
    "ipopt.acceptable_tol": 1e20,
    "ipopt.acceptable_constr_viol_tol": 1e-5,
    "ipopt.acceptable_dual_inf_tol": 1e20,
    "ipopt.acceptable_compl_inf_tol": 1e20,
    "ipopt.acceptable_obj_change_tol": 1e20,
    "ipopt.hessian_approximation": "limited-memory",
    # two L-BFGS pairs, not IPOPT's 6: each pair costs extra back-solves of the KKT system every
    # iteration (with ~2000 collision rows they were most of a full graph's solve). Recorded solves of
    # three runs (tower, obstacles, Hanoi; 1994 NLPs) replayed: as many iterations (-5 % to +1.5 %), the
    # same verdicts but one (a full graph "infeasible" before, feasible now), 16-38 % less CPU
    "ipopt.limited_memory_max_history": 2,
}
#: the conflict search's solves of subgraphs with arm variables add IPOPT's heuristics for problems
#: likely infeasible (the restoration phase entered sooner, left only after more reduction of the
#: violation): an "infeasible" verdict otherwise runs to the iteration limit. Replayed NLPs of a tower
#: and a Hanoi plan (1185 solves): the same verdict on every one, 40-50 % fewer IPOPT iterations. In
#: whole runs the search takes other paths, though, and they give up sooner: not on object-only
#: subgraphs (cheap anyway), where on obstacles_tower_pr2 seed 4 QuickXplain got false "infeasible"
#: verdicts (an obstacle left free and still "in the way": 15 conflicts refuted, 5 plans blocked), and
#: not in ``refute``, the check before a conflict is believed
SEARCH = {"ipopt.expect_infeasible_problem": "yes"}
#: random starts ``refute`` tries: fewer miss a false conflict too often; on a true conflict each try costs
#: ~0.2-0.8 s
REFUTE_TRIES = 8
#: random starts ``refute`` tries when LM answers (``GraphSolver.lm_refute``: fixed-base arms, subgraphs with
#: arm variables of up to ``LM_MAX_FACTORS`` factors): LM reaches a feasible point from fewer starts than
#: IPOPT but costs a fraction of its CPU per start, so twice the tries is a stronger check for less
REFUTE_TRIES_LM = 2 * REFUTE_TRIES
#: LM's steps per ``refute`` try at most: nearly every try that reaches a feasible point does so well within
#: it, while a try on a true conflict runs to the cap unless the violation stalls
REFUTE_LM_MAX_ITER = 30
#: an NLP of up to this many factors is solved from its guess only; a larger one found infeasible
#: there gets a second start, the arms' start postures. A small subgraph's "infeasible" verdict ends,
#: if at all, in a conflict that ``refute`` checks before it is believed (``conflicts.FILTER_MAX``:
#: the conflicts minimised and refuted are up to this size), and ``refute`` tries that start first;
#: larger ones (whole stretches of a plan) block a plan unchecked. The second start pays off only on
#: full-graph windows, so the conflict search gives it at the full graph only (``conflicts.RESTARTED``)
RESTART_ABOVE = 60
#: starts after the guess for an NLP over object poses only (cheap: a few ms each), each object's guess
#: perturbed (``X_JITTER``): from a guess with a block inside its neighbour a signed distance leads
#: nowhere, and the same false conflict is found and refuted again and again
OBJECT_STARTS = 2
#: ``refute`` of a subgraph with a pick from a known pose (a ``Kin`` whose world pose a ``Ref`` pins): every
#: other try starts from the seeder's IK with the base on another bearing round the object
#: (``guess.ik_seed``), the rest from random arm postures about the guess's base. Not for a place: its
#: object's pose is a guess, and the IK's held pose (at the tilt bound) a worse start than a random one
REFUTE_BEARINGS = True
#: [m] how far apart ``_cleared`` sets the objects that only collision factors name: one more start for an
#: object-only NLP, after ``OBJECT_STARTS``. In a relaxation without time such an object (an obstacle whose
#: ``Ref`` and ``Equal`` chain were relaxed away) can stand anywhere; from where it started, in the block's
#: way, the solver pushes the block into a corner and learns a false conflict; from it set aside, feasible
CLEAR_GAP = 0.3
#: with ``plan_gnpp(lm_verdicts=True)`` (the planner ``gnpp_trn_lm``) the conflict search's NLPs with arm
#: variables of up to this many factors get their verdict from ``lm.LevenbergMarquardt``, not IPOPT
#: (``refute``: LM by default, ``REFUTE_TRIES_LM``); a feasible point is then moved off the bounds it reached
#: (``LevenbergMarquardt.polish``). Not the default: LM's points sit on the rows' bounds, where the PR2's
#: collision spheres under-cover the upper arm and fingers, and some plans fail their replay. Fixed-base
#: arms only: with a mobile base it learns a conflict with the base held (EqualBase), not one for any base
#: pose. The measurements: ``docs/decisions/2026-11-solver-options.md``
LM_MAX_FACTORS = 60


STOP_ABOVE = 60  # factors: a larger graph-NLP's iterations also end once the budget is spent (``budget.ipopt_stop``)


def ipopt_options(n_factors: int, search: bool) -> dict:
    """The IPOPT options of a graph-NLP of ``n_factors`` factors (``search``: with ``SEARCH``); above
    ``STOP_ABOVE`` factors (a whole plan's, up to seconds) IPOPT stops once the budget is spent too (the small
    ones' ``max_cpu_time`` is a second or so, their iterations too cheap for a callback)."""
    stop = budget.ipopt_stop() if n_factors > STOP_ABOVE else {}
    return {**IPOPT, **(SEARCH if search else {}), **_limits(n_factors), **stop}


def _limits(n_factors: int) -> dict:
    """IPOPT's iteration and CPU-time limits for an NLP of ``n_factors`` factors: a verdict "infeasible"
    is the solver running into them, so they must not cut feasible solves short. Small NLPs get fewer
    iterations (their infeasible verdicts are the common kind), large ones (a whole plan) more time."""
    return {"ipopt.max_iter": min(60 + n_factors, 400), "ipopt.max_cpu_time": 1.0 + 0.012 * n_factors}


class Feasibility(enum.Enum):
    FEASIBLE = "feasible"
    INFEASIBLE = "infeasible"


@dataclass(frozen=True)
class SolveResult:
    feasibility: Feasibility
    values: Mapping[Var, FloatArray]  # the convergence point
    violations: tuple[float, ...]  # per factor, in the input order [m or rad]
    solve_s: float

    @property
    def feasible(self) -> bool:
        return self.feasibility is Feasibility.FEASIBLE


@dataclass(frozen=True)
class SolverRun:
    """One IPOPT run inside ``GraphSolver.solve``, for ``GraphSolver.observer`` (``tools/16``
    records them to re-solve them with other solvers). ``solver.oracle()`` is the NLP (x, p) -> (f, g);
    ``inputs`` are the run's arguments (x0, p, lbx, ubx, lbg, ubg); ``fixed_violation`` [m or rad] is the
    largest violation of the factors ``presolve`` took out of the NLP (constants, the same at any point):
    the run's verdict is "feasible" iff the NLP's rows and bounds hold within ``FEAS_TOL`` at its point
    and ``fixed_violation`` is within it too."""

    solver: ca.Function
    inputs: Mapping[str, FloatArray]
    n_factors: int
    arms: bool  # the NLP has arm variables
    search: bool  # IPOPT with ``SEARCH``
    feasible: bool
    iterations: int
    cpu_s: float
    fixed_violation: float


def run_feasible(oracle: ca.Function, x: FloatArray, inputs: Mapping[str, FloatArray], fixed_violation: float) -> bool:
    """A recorded run's verdict at the point ``x``, by ``SolverRun``'s rule: every row of the NLP
    ``oracle`` (x, p) -> (f, g) and every variable bound within ``FEAS_TOL`` (``inputs``: the run's p, lbg,
    ubg, lbx, ubx), and the factors ``presolve`` made constants within it too."""
    x = np.asarray(x, float).reshape(-1)
    if not np.all(np.isfinite(x)):
        return False
    g = np.asarray(oracle(x, inputs["p"])[1]).reshape(-1)
    over = np.r_[inputs["lbg"] - g, g - inputs["ubg"], inputs["lbx"] - x, x - inputs["ubx"], 0.0]
    return bool(np.all(np.isfinite(g))) and float(over.max()) <= FEAS_TOL and fixed_violation <= FEAS_TOL


@dataclass
class _Built:
    nlp: dict | None  # the NLP {"x", "p", "f", "g"}; None: every variable pinned (nothing to solve)
    options: dict  # IPOPT's
    lm: LevenbergMarquardt | None  # the verdict solver of a small arm NLP (``LM_MAX_FACTORS``, ``lm_refute``)
    search: bool  # IPOPT runs with ``SEARCH``
    g_fn: BufferedFunction  # the NLP's free variables -> every input factor's rows
    lbg: FloatArray  # bounds of the NLP's rows (the factors ``pre.kept``)
    ubg: FloatArray
    lo_all: FloatArray  # bounds of every input factor's rows (``g_fn``)
    hi_all: FloatArray
    rows: list[tuple[int, int]]  # per input factor: its row range in ``g_fn``
    pre: Presolved
    polisher: LevenbergMarquardt | None = None  # sparse, for ``GraphSolver.polish``
    _ipopt: ca.Function | None = None

    @property
    def solver(self) -> ca.Function | None:
        """IPOPT on ``nlp``, built at first use (a structure ``lm`` answers for never needs it)."""
        if self._ipopt is None and self.nlp is not None:
            self._ipopt = ca.nlpsol("graph_nlp", "ipopt", self.nlp, {**self.options, **LEAN})
        return self._ipopt


class GraphSolver:
    """Solves subgraphs of one scene's graph-NLPs; ``n_solves`` counts the NLPs solved (a subgraph of
    more than ``RESTART_ABOVE`` factors found infeasible from the given start is solved ``restarts``
    more times, from the arms' start postures: the solver is local, and a false "infeasible" would
    forbid feasible plans; smaller ones are checked by ``refute``, which starts there)."""

    def __init__(self, lib: FactorLib, restarts: int = 1) -> None:
        self.lib, self.restarts = lib, restarts
        #: optional: (factors, guess, bearing) -> a start for ``refute``'s tries (the planner sets one for a
        #: mobile arm: top-grasp IK at each kinematic switch, ``guess.ik_seed``; the HSR's folded start
        #: posture converges to a top grasp from few random starts). ``bearing`` 0: the IK from the guess's
        #: base; k > 0: from the k-th base on a ring round the object (``REFUTE_BEARINGS``)
        self.seeder: Callable[[Sequence[Factor], Mapping[Var, FloatArray], int], Mapping[Var, FloatArray]] | None = None
        self.n_solves = 0
        self.solve_time_s = 0.0
        self.thorough = False  # IPOPT without ``SEARCH`` (``refute`` sets it)
        self._cache: dict[tuple, _Built] = {}
        #: ``graph.structure`` of each subgraph ``refute`` found a feasible point for -> that point by position
        #: (``graph.canonical``): the same problem met again (another plan's pick of the same object from
        #: its start) starts from it, in the search's solves (up to ``RESTART_ABOVE`` factors) and in
        #: ``refute``, not from a guess or random starts that may all miss it this time
        self._refuted: dict[tuple, dict[int, FloatArray]] = {}
        #: ``graph.structure`` of each subgraph ``refute`` found no feasible point for -> its tries
        self._upheld: dict[tuple, int] = {}
        self.iters: list[int] = []  # iterations per solver run (IPOPT's, or LM's)
        #: called after every IPOPT run (a diagnostic hook: ``tools/16_gnpp_nlp_corpus.py``)
        self.observer: Callable[[SolverRun], None] | None = None
        #: the search's arm NLPs of up to this many factors answered by LM (``LM_MAX_FACTORS``); 0: IPOPT only
        self.lm_max_factors = 0
        #: ``refute``'s tries on fixed-base arm subgraphs of up to ``LM_MAX_FACTORS`` factors by LM
        #: (``REFUTE_TRIES_LM`` of them), not IPOPT
        self.lm_refute = True

    def polish(self, factors: Sequence[Factor], values: Mapping[Var, FloatArray]) -> Mapping[Var, FloatArray]:
        """A feasible point ``values`` of the subgraph (a whole plan's, before it is laid out as motions)
        moved ``lm.BACKOFF`` inside its inequality rows where a few sparse Levenberg-Marquardt steps can
        without leaving the rows (``LevenbergMarquardt.polish``), else ``values``. A local solver stops on
        the first feasible point, often with a clearance row at its bound (the fingers at their margin
        to an obstacle): the replay's meshes then touch, and the plan is thrown away."""
        order = variables(factors)
        built = self._built(factors, order)
        if built.nlp is None:
            return values
        if built.polisher is None:
            nlp = built.nlp
            built.polisher = LevenbergMarquardt(nlp["x"], nlp["p"], nlp["g"], 0, sparse=True)
        pre = built.pre
        free = [order[i] for i in pre.free]
        lbx, ubx = self._box(free)
        x = np.concatenate([np.asarray(values[v], float) for v in free])
        moved = built.polisher.polish(x, x, lbx, ubx, built.lbg, built.ubg)
        if moved is x or not _violations(built, moved)[1]:
            return values
        return self._unpack(order, pre, free, moved)

    def _built(self, factors: Sequence[Factor], order: list[Var]) -> _Built:
        """The subgraph's NLP, from the cache of structures or built."""
        key = self._structure(factors, order)
        built = self._cache.get(key)
        if built is None:
            built = self._cache[key] = self._build(factors, order)
        return built

    def _box(self, free: Sequence[Var]) -> tuple[FloatArray, FloatArray]:
        """The bounds (lbx, ubx) of the NLP variables ``free``."""
        bounds = [self.lib.var_bounds(v.kind, v.owner) for v in free]
        lbx = np.concatenate([b[0] for b in bounds]) if free else np.zeros(0)
        ubx = np.concatenate([b[1] for b in bounds]) if free else np.zeros(0)
        return lbx, ubx

    def _unpack(self, order: list[Var], pre: Presolved, free: Sequence[Var], xs: FloatArray) -> dict[Var, FloatArray]:
        """Every variable's value: the NLP point ``xs`` of the ``free`` ones, the pinned ones' constants."""
        offs = np.cumsum([0, *[self.lib.dim(v.kind, v.owner) for v in free]])
        values = {}
        for i, v in enumerate(order):
            kind, where = pre.slot_of(i)
            values[v] = np.array(where, float) if kind == "const" else xs[offs[where] : offs[where + 1]].copy()
        return values

    def _structure(self, factors: Sequence[Factor], order: list[Var]) -> tuple:
        pos = {v: i for i, v in enumerate(order)}
        return (
            self.thorough,
            tuple(v.label for v in order),
            tuple((f.key, tuple(pos[v] for v in f.vars)) for f in factors),
        )

    def _build(self, factors: Sequence[Factor], order: list[Var]) -> _Built:
        pre = presolve(self.lib, factors, order)
        nlp_rows = assemble(self.lib, factors, order, pre)
        x, g = nlp_rows.x, nlp_rows.g
        p = ca.MX.sym("p", x.numel())
        arms = any(order[i].kind == "q" for i in pre.free)
        search = not self.thorough and any(v.kind == "q" for v in order)
        options = ipopt_options(len(factors), search)
        nlp = {"x": x, "p": p, "f": W_REG * ca.sumsqr(x - p), "g": g} if pre.free else None
        lm = None
        cap = (LM_MAX_FACTORS if self.lm_refute else 0) if self.thorough else self.lm_max_factors
        if nlp is not None and arms and len(factors) <= cap and not self.lib.mobile:
            lm = LevenbergMarquardt(x, p, g, REFUTE_LM_MAX_ITER if self.thorough else options["ipopt.max_iter"])
        g_fn = BufferedFunction(ca.Function("g", [x], [nlp_rows.g_all]))
        return _Built(
            nlp, options, lm, search, g_fn, nlp_rows.lbg, nlp_rows.ubg, nlp_rows.lo_all, nlp_rows.hi_all,
            list(nlp_rows.rows), pre,
        )

    def _observe(
        self,
        built: _Built,
        factors: Sequence[Factor],
        order: list[Var],
        x0: FloatArray,
        lbx: FloatArray,
        ubx: FloatArray,
        viol: tuple[float, ...],
        feasible: bool,
        cpu: float,
    ) -> None:
        """``observer`` told of the IPOPT run just made (``SolverRun``)."""
        assert self.observer is not None and built.solver is not None
        pre, pos = built.pre, {v: i for i, v in enumerate(order)}
        constant = [k for k, f in enumerate(factors) if all(pre.rep[pos[v]] in pre.const for v in f.vars)]
        inputs = {"x0": x0, "p": x0, "lbx": lbx, "ubx": ubx, "lbg": built.lbg, "ubg": built.ubg}
        arms = any(order[i].kind == "q" for i in pre.free)
        fixed = max((viol[k] for k in constant), default=0.0)
        run = SolverRun(built.solver, inputs, len(factors), arms, built.search, feasible, self.iters[-1], cpu, fixed)
        self.observer(run)

    def refute(
        self, factors: Sequence[Factor], guess: Mapping[Var, FloatArray], tries: int | None = None, seed: int = 0
    ) -> Mapping[Var, FloatArray] | None:
        """A feasible point of the subgraph found from the arms' start postures (if it has arm variables:
        ``solve``'s second start, which the search gives small subgraphs no more) or one of ``tries``
        seeded random starts, or None: the check of a conflict before it is used (the solver is
        local). Arms start perturbed about their start postures; objects about their guessed poses (a
        few cm, a fraction of a turn), which also separates objects the guess put on top of each
        other. LM tries (``REFUTE_TRIES_LM`` by default) where ``lm_refute`` applies, else IPOPT without
        ``SEARCH`` (``REFUTE_TRIES``); a point LM finds is moved off its bounds (``LevenbergMarquardt.polish``).
        A subgraph with the same ``graph.structure`` as one checked before from as many starts (the same
        problem, e.g. a conflict learnt again with its object held a step longer) is not solved again:
        None. (Hanoi: 6 of its 12 conflicts.)"""
        key, pos = canonical(factors)
        if key in self._refuted:  # checked from that point (``solve`` starts there: one solve)
            restarts, self.restarts, self.thorough = self.restarts, 0, True
            try:
                res = self.solve(factors, guess)
            finally:
                self.restarts, self.thorough = restarts, False
            if res.feasible:
                log.debug("the same problem as a subgraph refuted before: refuted from its point")
                return res.values
        if self._upheld.get(key, -1) >= (REFUTE_TRIES if tries is None else tries):
            log.debug("the same problem as a subgraph checked before, not refuted")
            return None
        rng = np.random.default_rng(seed)
        restarts, self.restarts, self.thorough = self.restarts, 0, True
        try:
            if tries is None:
                lm = self._built(factors, variables(factors)).lm is not None
                tries = REFUTE_TRIES_LM if lm else REFUTE_TRIES
            point = self._refute(factors, guess, tries, rng)
        finally:
            self.restarts, self.thorough = restarts, False
        if point is None:
            self._upheld[key] = max(tries, self._upheld.get(key, -1))
        else:
            self._refuted[key] = {pos[v]: np.asarray(x, float).copy() for v, x in point.items() if v in pos}
        return point

    def _refute(
        self, factors: Sequence[Factor], guess: Mapping[Var, FloatArray], tries: int, rng: np.random.Generator
    ) -> Mapping[Var, FloatArray] | None:
        order = variables(factors)
        if any(v.kind == "q" for v in order):
            res = self.solve(factors, {v: self._home_start(v, guess[v]) for v in order})
            if res.feasible:
                return res.values
        pinned = {f.vars[0] for f in factors if f.kind == "Ref"}
        kin = any(f.kind == "Kin" and f.vars[1] in pinned for f in factors)  # a pick from a known pose
        for k in range(tries):
            start = {v: self._jittered(v, guess[v], rng) for v in order}
            if self.seeder is not None and (k == 0 or (kin and k % 2 == 1 and REFUTE_BEARINGS)):
                # the first try from the seeder's start (the guess's base), every other one from its IK
                # with the base on the next bearing round the object: random arm postures about one base
                # all fail where that base only reaches at the tilt bound
                start = dict(self.seeder(factors, {v: guess[v] for v in start}, (k + 1) // 2))
            res = self.solve(factors, start)
            if res.feasible:
                return res.values
        return None

    def _jittered(self, v: Var, guess: FloatArray, rng: np.random.Generator) -> FloatArray:
        """A random start for ``refute``: an arm's start posture perturbed, an object's guess perturbed.
        A mobile arm's base about its guess (its start base is rarely near the keyframe)."""
        if v.kind != "q":
            return np.asarray(guess, float) + rng.normal(0.0, 1.0, 4) * X_JITTER
        home = self.lib.home_q(v.owner)
        if self.lib.mobile:
            home[:3] = np.asarray(guess, float)[:3]
        return home + rng.normal(0.0, 0.5, home.size)

    def _home_start(self, v: Var, guess: FloatArray) -> FloatArray:
        """``solve``'s second start for a variable: an arm at its start posture (a mobile arm's base
        where the guess has it), an object at its guess."""
        if v.kind != "q":
            return guess
        home = self.lib.home_q(v.owner)
        if self.lib.mobile:
            home[:3] = np.asarray(guess, float)[:3]
        return home

    def solve(self, factors: Sequence[Factor], guess: Mapping[Var, FloatArray]) -> SolveResult:
        """Solve the subgraph spanned by ``factors`` from ``guess`` (every variable needs one)."""
        t0 = time.perf_counter()
        order = variables(factors)
        if self._refuted and len(factors) <= RESTART_ABOVE:
            key, pos = canonical(factors)
            known = self._refuted.get(key)
            if known is not None:  # a problem ``refute`` solved before: its point is the first start
                guess = {**guess, **{v: known[pos[v]] for v in order if pos.get(v) in known}}
        built = self._built(factors, order)
        pre = built.pre
        free = [order[i] for i in pre.free]
        lbx, ubx = self._box(free)
        eff, movable = {}, {}  # each variable's start (a pinned one: its constant); the free ones' NLP variable
        for i, v in enumerate(order):
            kind, where = pre.slot_of(i)
            if kind == "const":
                eff[v] = np.asarray(where, float)
            else:
                movable[v] = order[pre.rep[i]]
                eff[v] = guess[movable[v]]
        guess = _apart(factors, eff, movable)
        starts = [np.concatenate([guess[v] for v in free]) if free else np.zeros(0)]
        if any(v.kind == "q" for v in free):  # a second start: every arm at its start posture (base kept)
            starts.append(np.concatenate([self._home_start(v, guess[v]) for v in free]))
            starts = starts[: 1 + (self.restarts if len(factors) > RESTART_ABOVE else 0)]
        elif free:  # objects only: a few ms a solve; OBJECT_STARTS more, each object's guess perturbed
            rng = np.random.default_rng(len(factors))
            starts += [np.concatenate([self._jittered(v, guess[v], rng) for v in free]) for _ in range(OBJECT_STARTS)]
            aside = _cleared(factors, guess, movable)
            if aside is not None:
                starts.append(np.concatenate([aside.get(v, guess[v]) for v in free]))
        for x0 in starts:
            x0 = np.clip(x0, lbx, ubx)
            xs = x0
            if built.lm is not None:
                xs = np.asarray(built.lm(x0=x0, p=x0, lbx=lbx, ubx=ubx, lbg=built.lbg, ubg=built.ubg)["x"])
                self.iters.append(int(built.lm.stats()["iter_count"]))
            elif built.solver is not None:
                c0 = time.process_time()
                res = built.solver(x0=x0, p=x0, lbx=lbx, ubx=ubx, lbg=built.lbg, ubg=built.ubg)
                budget.check()  # IPOPT stopped by ``budget.ipopt_stop``: no verdict
                cpu = time.process_time() - c0
                self.iters.append(int(built.solver.stats()["iter_count"]))
                xs = np.asarray(res["x"]).reshape(-1)
            viol, feasible = _violations(built, xs)
            if built.lm is not None and feasible:  # the verdict stands; the point (a warm start) off its bounds
                moved = built.lm.polish(xs, x0, lbx, ubx, built.lbg, built.ubg)
                if moved is not xs:
                    xs = moved
                    viol, feasible = _violations(built, xs)
            if self.observer is not None and built.lm is None and built.nlp is not None:
                self._observe(built, factors, order, x0, lbx, ubx, viol, feasible, cpu)
            if feasible:
                break
        values = self._unpack(order, pre, free, xs)
        ok = feasible
        dt = time.perf_counter() - t0
        self.n_solves += 1
        self.solve_time_s += dt
        log.debug(
            "NLP %d: %d factors, %d vars: %s (%.1f ms, IPOPT iterations %s)",
            *(self.n_solves, len(factors), len(order), ok, dt * 1e3, self.iters[-2:]),
        )
        return SolveResult(Feasibility.FEASIBLE if ok else Feasibility.INFEASIBLE, values, viol, dt)


def _violations(built: _Built, xs: FloatArray) -> tuple[tuple[float, ...], bool]:
    """(every input factor's violation at the free variables' values ``xs``, all within ``FEAS_TOL``)."""
    (nz,) = built.g_fn(xs)
    g = built.g_fn.dense(0, nz).reshape(-1)
    over = np.maximum(np.maximum(built.lo_all - g, g - built.hi_all), 0.0)
    over[~np.isfinite(g)] = np.inf
    viol = tuple(float(over[a:b].max()) if b > a else 0.0 for a, b in built.rows)
    return viol, bool(np.all(np.isfinite(xs))) and max(viol, default=0.0) <= FEAS_TOL


def _cleared(
    factors: Sequence[Factor], start: Mapping[Var, FloatArray], movable: Mapping[Var, Var]
) -> dict[Var, FloatArray] | None:
    """The free objects (``movable``'s values: each stands for the variables ``presolve`` made one) that only
    collision factors name, each at a start set aside: ``CLEAR_GAP`` apart in a row beyond every other
    object in ``start`` (+x, at their mean y); None if there is none. A start only: the verdict stays the
    solver's at the point it reaches."""
    named: dict[Var, bool] = {}  # free variable -> named by collision factors only
    for f in factors:
        for v in f.vars:
            if v in movable:
                named[movable[v]] = named.get(movable[v], True) and f.collision
    aside = sorted((v for v, only in named.items() if only), key=str)
    if not aside:
        return None
    rest = [np.asarray(w, float) for v, w in start.items() if movable.get(v) not in aside]
    x0 = max((float(w[0]) for w in rest), default=0.0) + CLEAR_GAP
    y0 = float(np.mean([w[1] for w in rest])) if rest else 0.0
    return {v: np.r_[x0 + CLEAR_GAP * k, y0, np.asarray(start[v], float)[2:]] for k, v in enumerate(aside)}


def _apart(
    factors: Sequence[Factor], guess: Mapping[Var, FloatArray], movable: Mapping[Var, Var]
) -> Mapping[Var, FloatArray]:
    """``guess`` with resting objects that a ColOO factor keeps apart and that start at one point moved
    apart (a few cm, in a fixed direction per pair): there a signed distance has no gradient, and
    the solver stays stuck (a false "infeasible" that ``refute`` would have to catch). ``movable``: the
    free variables, each to its NLP variable after ``presolve`` (the one whose start counts); the
    second object's is moved if it is free, else the first's; two pinned objects stay."""
    out: dict[Var, FloatArray] | None = None
    for k, f in enumerate(factors):
        if f.kind != "ColOO":
            continue
        a, b = (movable.get(v, v) for v in f.vars)
        mover = b if f.vars[1] in movable else a if f.vars[0] in movable else None
        if mover is None or a == b:
            continue
        cur = out if out is not None else guess
        if float(np.linalg.norm(np.asarray(cur[a])[:2] - np.asarray(cur[b])[:2])) < 1e-3:
            if out is None:
                out = dict(guess)
            ang = 2.399963 * k  # the golden angle: pairs move in different directions
            out[mover] = np.asarray(out[mover], float) + np.array([0.05 * np.cos(ang), 0.05 * np.sin(ang), 0.0, 0.0])
    return guess if out is None else out
