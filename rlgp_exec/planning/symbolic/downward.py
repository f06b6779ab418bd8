"""Fast Downward runner: PDDL text in, a status and ground actions out — never an exception from inside.

The planner is the ``fast-downward.py`` driver shipped in the ``up_fast_downward`` wheel, run in a
subprocess with a wall-clock timeout, in a fresh temporary directory (so concurrent calls do not
share ``output.sas`` / ``sas_plan``).

Search configurations (measured on the shipped scenes, see ``tools/05_symbolic_plans.py``):
``lama-first`` (the default; ~0.2 s per call, supports the conditional effects of the GNPP
reformulation, plans not guaranteed shortest) and ``optimal`` = ``astar(lmcut())`` for shortest
plans of the plain domain (lmcut has no conditional effects, so on a reformulated problem
``optimal`` switches to ``astar(hmax())``, which has).
"""

from __future__ import annotations

import enum
import importlib.util
import logging
import re
import subprocess
import sys
import tempfile
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.ground_pddl import ground_to_pddl
from rlgp_exec.planning.symbolic.model import GroundAction, GroundProblem
from rlgp_exec.planning.symbolic.pddl import domain_to_pddl, load_domain
from rlgp_exec.planning.symbolic.problem import ProblemSpec, problem_to_pddl

__all__ = [
    "SEARCHES",
    "FDResult",
    "FDStatus",
    "fast_downward_script",
    "run_fast_downward",
    "solve_ground",
    "solve_spec",
]

log = logging.getLogger(__name__)

#: named search configurations -> driver arguments
SEARCHES: Mapping[str, tuple[str, ...]] = {
    "lama-first": ("--alias", "lama-first"),
    "optimal": ("--search", "astar(lmcut())"),
    "optimal-ce": ("--search", "astar(hmax())"),
    "blind": ("--search", "astar(blind())"),
}
_CONDITIONAL = {"optimal": "optimal-ce"}


class FDStatus(enum.Enum):
    SOLVED = "solved"
    UNSOLVABLE = "unsolvable"  # proven: no plan exists
    UNSOLVED = "unsolved"  # search ended without a plan and without a proof (incomplete search)
    TIMEOUT = "timeout"
    MISSING_BINARY = "missing_binary"
    UNSUPPORTED = "unsupported"  # the configuration does not support the input (e.g. lmcut + conditional effects)
    ERROR = "error"  # bad input or a crash; see ``reason``


# Fast Downward driver exit codes (driver/returncodes.py)
_EXIT: dict[int, FDStatus] = {
    0: FDStatus.SOLVED,
    10: FDStatus.UNSOLVABLE,  # translate: unsolvable
    11: FDStatus.UNSOLVABLE,  # search: unsolvable
    12: FDStatus.UNSOLVED,  # search: unsolved, incomplete
    22: FDStatus.ERROR,  # translate out of memory
    23: FDStatus.TIMEOUT,  # translate out of time
    32: FDStatus.ERROR,  # search critical error
    33: FDStatus.ERROR,  # search input error
    34: FDStatus.UNSUPPORTED,
    35: FDStatus.ERROR,  # search out of memory (also 36/37: time, memory+time)
    36: FDStatus.TIMEOUT,
    37: FDStatus.TIMEOUT,
}


@dataclass(frozen=True)
class FDResult:
    status: FDStatus
    plan: tuple[GroundAction, ...] = ()
    cost: int | None = None
    wall_time_s: float = 0.0
    reason: str = ""
    search: str = ""
    log_tail: str = field(default="", repr=False)

    @property
    def solved(self) -> bool:
        return self.status is FDStatus.SOLVED


def fast_downward_script() -> Path | None:
    """The ``fast-downward.py`` driver of the installed ``up_fast_downward`` package, or None."""
    spec = importlib.util.find_spec("up_fast_downward")  # not imported: it pulls in unified_planning
    if spec is None or spec.origin is None:
        return None
    path = Path(spec.origin).parent / "downward" / "fast-downward.py"
    return path if path.is_file() else None


_PLAN_LINE = re.compile(r"^\(([^()]*)\)\s*$")
_COST = re.compile(r"^;\s*cost\s*=\s*(\d+)")


def _parse_plan(
    text: str, names: Mapping[str, str] | None, actions_by_name: Mapping[str, GroundAction] | None
) -> tuple[list[GroundAction], int | None]:
    actions: list[GroundAction] = []
    cost = None
    for line in text.splitlines():
        m = _COST.match(line.strip())
        if m:
            cost = int(m.group(1))
            continue
        m = _PLAN_LINE.match(line.strip())
        if not m:
            continue
        parts = m.group(1).split()
        if actions_by_name is not None:
            if parts[0] not in actions_by_name:
                raise ValueError(f"plan names unknown action {parts[0]!r}")
            actions.append(actions_by_name[parts[0]])
            continue
        if names is not None:
            parts = [names.get(p, p) for p in parts]
        actions.append(GroundAction(parts[0], tuple(parts[1:])))
    return actions, cost


def run_fast_downward(
    domain_pddl: str,
    problem_pddl: str,
    *,
    search: str = "lama-first",
    timeout_s: float = 30.0,
    names: Mapping[str, str] | None = None,
    actions_by_name: Mapping[str, GroundAction] | None = None,
    conditional_effects: bool = False,
    script: Path | str | None = None,
    extra_args: Sequence[str] = (),
) -> FDResult:
    """Plan with Fast Downward; the result's status says how it ended (see :class:`FDStatus`).

    ``names`` maps the lower-cased names in FD's plan back to ours (FD lower-cases everything),
    ``actions_by_name`` maps whole action names (ground PDDL, see ``ground_pddl``) to our actions;
    ``search`` is a key of :data:`SEARCHES` or a raw ``--search`` argument like ``astar(ff())``;
    ``script`` overrides the driver (e.g. for tests of a missing binary).
    """
    t0 = time.perf_counter()
    if search in SEARCHES:
        key = _CONDITIONAL.get(search, search) if conditional_effects else search
        args = list(SEARCHES[key])
    elif "(" in search:
        args = ["--search", search]
    else:
        return FDResult(
            FDStatus.ERROR,
            reason=f"unknown search {search!r}; valid: {list(SEARCHES)} or a raw configuration like 'astar(ff())'",
            search=search,
        )
    driver = Path(script) if script is not None else fast_downward_script()
    if driver is None or not driver.is_file():
        return FDResult(
            FDStatus.MISSING_BINARY,
            reason=f"Fast Downward driver not found at {driver} (install up-fast-downward)",
            search=search,
        )
    with tempfile.TemporaryDirectory(prefix="rlgp_fd_") as tmp:
        d = Path(tmp)
        (d / "domain.pddl").write_text(domain_pddl)
        (d / "problem.pddl").write_text(problem_pddl)
        plan_file = d / "sas_plan"
        if args[0] == "--alias":
            cmd = [
                sys.executable,
                str(driver),
                "--plan-file",
                str(plan_file),
                *args,
                str(d / "domain.pddl"),
                str(d / "problem.pddl"),
                *extra_args,
            ]
        else:
            cmd = [
                sys.executable,
                str(driver),
                "--plan-file",
                str(plan_file),
                str(d / "domain.pddl"),
                str(d / "problem.pddl"),
                *args,
                *extra_args,
            ]
        try:
            proc = subprocess.run(cmd, cwd=d, capture_output=True, text=True, timeout=timeout_s, check=False)
        except subprocess.TimeoutExpired:
            wall = time.perf_counter() - t0
            log.info("Fast Downward timed out after %.2f s (%s)", wall, search)
            return FDResult(FDStatus.TIMEOUT, wall_time_s=wall, reason=f"no answer within {timeout_s} s", search=search)
        except OSError as e:
            return FDResult(
                FDStatus.MISSING_BINARY,
                wall_time_s=time.perf_counter() - t0,
                reason=f"cannot run {driver}: {e}",
                search=search,
            )
        wall = time.perf_counter() - t0
        tail = "\n".join((proc.stdout + proc.stderr).strip().splitlines()[-15:])
        status = _EXIT.get(proc.returncode, FDStatus.ERROR)
        if status is FDStatus.SOLVED:
            if not plan_file.is_file():
                return FDResult(
                    FDStatus.ERROR,
                    wall_time_s=wall,
                    reason="exit 0 but no sas_plan written",
                    search=search,
                    log_tail=tail,
                )
            try:
                plan, cost = _parse_plan(plan_file.read_text(), names, actions_by_name)
            except ValueError as e:
                return FDResult(
                    FDStatus.ERROR, wall_time_s=wall, reason=f"cannot read sas_plan: {e}", search=search, log_tail=tail
                )
            log.debug("Fast Downward (%s): %d actions in %.2f s", search, len(plan), wall)
            return FDResult(status, tuple(plan), cost, wall, search=search, log_tail=tail)
        reason = f"exit code {proc.returncode}"
        errors = [ln for ln in tail.splitlines() if "error" in ln.lower() or "unsupported" in ln.lower()]
        if errors:
            reason += ": " + errors[-1].strip()
        log.info("Fast Downward (%s): %s (%s)", search, status.value, reason)
        return FDResult(status, wall_time_s=wall, reason=reason, search=search, log_tail=tail)


def solve_spec(spec: ProblemSpec, *, search: str = "lama-first", timeout_s: float = 30.0) -> FDResult:
    """Fast Downward on the lifted domain (``spec.domain_name``) and ``spec``."""
    try:
        domain = load_domain(spec.domain_name)
    except SymbolicError as e:
        return FDResult(FDStatus.ERROR, reason=str(e), search=search)
    names = {n.lower(): n for n, _ in spec.objects}
    return run_fast_downward(
        domain_to_pddl(domain), problem_to_pddl(spec), search=search, timeout_s=timeout_s, names=names
    )


def solve_ground(problem: GroundProblem, *, search: str = "lama-first", timeout_s: float = 30.0) -> FDResult:
    """Fast Downward on a ground copy of ``problem`` (e.g. a GNPP reformulation)."""
    g = ground_to_pddl(problem)
    return run_fast_downward(
        g.domain,
        g.problem,
        search=search,
        timeout_s=timeout_s,
        actions_by_name=g.actions,
        conditional_effects=g.conditional_effects,
    )
