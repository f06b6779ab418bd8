"""The symbolic layer shared by R-LGP and GNPP.

* ``domains/mobile_manipulation.pddl`` — the domain, the single definition (parsed by ``pddl``);
* ``problem`` — a Scene -> typed objects, initial state and goal (``problem_from_scene``);
* ``grounding`` / ``model`` — STRIPS operators, ``successors``, ``is_goal``, ``simulate``;
* ``search`` / ``heuristics`` — ``best_first`` with a pluggable cost (or a path-dependent ``PathCost``),
  yielding candidate plans;
* ``relevance`` — ``without_detours``: operators that only take an object off its goal surface, removed;
* ``stacking`` — towers and Hanoi: which objects are in place for good, the count of those that are not,
  and the prunings that follow (R-LGP's search);
* ``downward`` — Fast Downward in a subprocess, failures as ``FDStatus``;
* ``reformulate`` — GNPP: forbid learnt infeasible partial-state sequences (both planners).
"""

from rlgp_exec.planning.symbolic.downward import (
    SEARCHES,
    FDResult,
    FDStatus,
    fast_downward_script,
    run_fast_downward,
    solve_ground,
    solve_spec,
)
from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.ground_pddl import GroundPDDL, ground_to_pddl
from rlgp_exec.planning.symbolic.grounding import ground, ground_scene
from rlgp_exec.planning.symbolic.heuristics import distance_cost, goal_lower_bound, site_positions
from rlgp_exec.planning.symbolic.model import (
    Atom,
    CondEffect,
    GroundAction,
    GroundProblem,
    Operator,
    SymbolicState,
    atom_str,
    parse_atom,
)
from rlgp_exec.planning.symbolic.pddl import DOMAINS, ActionSchema, Domain, domain_to_pddl, load_domain, parse_domain
from rlgp_exec.planning.symbolic.problem import ProblemSpec, problem_from_scene, problem_to_pddl
from rlgp_exec.planning.symbolic.reformulate import (
    ActionPattern,
    ForbiddenActions,
    ForbiddenSequence,
    PartialState,
    Reformulation,
    reformulate,
    violates,
)
from rlgp_exec.planning.symbolic.relevance import without_detours
from rlgp_exec.planning.symbolic.search import BestFirst, CandidatePlan, PathCost, SearchStats, best_first, unit_cost

__all__ = [
    "DOMAINS",
    "SEARCHES",
    "ActionPattern",
    "ActionSchema",
    "Atom",
    "BestFirst",
    "CandidatePlan",
    "CondEffect",
    "Domain",
    "FDResult",
    "FDStatus",
    "ForbiddenActions",
    "ForbiddenSequence",
    "GroundAction",
    "GroundPDDL",
    "GroundProblem",
    "Operator",
    "PartialState",
    "PathCost",
    "ProblemSpec",
    "Reformulation",
    "SearchStats",
    "SymbolicError",
    "SymbolicState",
    "atom_str",
    "best_first",
    "distance_cost",
    "domain_to_pddl",
    "fast_downward_script",
    "goal_lower_bound",
    "ground",
    "ground_scene",
    "ground_to_pddl",
    "load_domain",
    "parse_atom",
    "parse_domain",
    "problem_from_scene",
    "problem_to_pddl",
    "reformulate",
    "run_fast_downward",
    "site_positions",
    "solve_ground",
    "solve_spec",
    "unit_cost",
    "violates",
    "without_detours",
]
