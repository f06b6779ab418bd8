"""The planners' output: a ``Plan`` (actions, keyframes, joint paths per phase, costs, counters)."""

from __future__ import annotations

from dataclasses import asdict, dataclass, field

import numpy as np

from rlgp_exec.planning.validate import Phase, Validation
from rlgp_exec.robot.model import FloatArray

__all__ = ["Level3Stats", "Plan"]


@dataclass(frozen=True)
class Level3Stats:
    """Level 3 (full-path optimisation, ``nlp.path``) over one planning call (every candidate tried)."""

    attempts: int = 0  # path NLPs solved
    solved: int = 0  # of them feasible and not costlier than their warm start
    used: int = 0  # candidate plans whose replay passed with level-3 paths in them
    fallbacks: int = 0  # segments put back to the graph's path after a replay collision
    time_s: float = 0.0  # building and solving the path NLPs [s]
    acc_cost: float | None = None  # the returned plan's acceleration cost (its level-3 segments)
    warm_acc_cost: float | None = None  # the same segments' warm start (graph waypoints resampled)
    jac_nnz: int | None = None  # the last level-3 call's constraint-Jacobian non-zeros (all its segments)
    n_var: int | None = None  # and its variables


@dataclass(frozen=True)
class Plan:
    """A planner's answer for a scene's goal: the symbolic actions, the keyframes (K, nq) at which the hand's
    mode switches, and the joint paths (``phases``) between them, in the robot's planning joints (the base's
    x [m], y [m], yaw [rad] first on a mobile robot, then each joint [rad or m]). ``success`` only when the
    plan was replayed in PyBullet (``validation``): collision-free and the goal met; otherwise ``reason``
    says why not. Time it with :func:`rlgp_exec.to_trajectory`."""

    success: bool  # validated: collision-free replay and goal met
    planner: str
    actions: tuple[str, ...]
    keyframes: FloatArray  # (K, nq) the mode-switch configurations
    phases: tuple[Phase, ...]  # joint paths between keyframes (the first starts at the start)
    planning_time_s: float
    n_nlp: int  # NLPs solved (keyframe problems)
    nodes_expanded: int  # symbolic search
    validation: Validation | None
    reason: str
    counters: dict = field(default_factory=dict)  # planner-specific counts (GNPP: n0, n, nlp, ...)
    level3: Level3Stats | None = None  # R-LGP's full-path optimisation (None: not run)
    #: R-LGP: wall time [s] per stage of the geometric layer (``sequence.STAGES``), summed over the candidates
    stages: dict[str, float] = field(default_factory=dict)
    #: R-LGP, on failure: the first ``doomed`` actions cannot be realised whatever follows them (0: not known)
    doomed: int = 0

    @property
    def base_path_length_m(self) -> float:
        total = 0.0
        for ph in self.phases:
            if len(ph.path) > 1:
                total += float(np.sum(np.linalg.norm(np.diff(ph.path[:, :2], axis=0), axis=1)))
        return total

    def summary(self) -> dict:
        """The ``plan --json`` fields (DESIGN.md)."""
        return {
            "success": self.success,
            "planner": self.planner,
            "planning_time_s": self.planning_time_s,
            "actions": list(self.actions),
            "n_steps": len(self.actions),
            "base_path_length_m": self.base_path_length_m,
            "collision_free": None if self.validation is None else self.validation.collision_free,
            "goal_met": None if self.validation is None else self.validation.goal_met,
            "n_nlp": self.n_nlp,
            "nodes_expanded": self.nodes_expanded,
            "reason": self.reason,
            **({"counters": dict(self.counters)} if self.counters else {}),
            **({"level3": asdict(self.level3)} if self.level3 is not None else {}),
            **({"stages_s": dict(self.stages)} if self.stages else {}),
        }
