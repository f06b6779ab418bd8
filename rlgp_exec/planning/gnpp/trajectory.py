"""GNPP's trajectories (paper, appendix C): once the mode switches are solved, each acting arm's move
to its next keyframe is warm-started as the linear interpolation between them and re-optimised as
``T_TRAJ`` = 20 waypoints.

The NLP is the one R-LGP's level 3 solves (``nlp.path``, the same factors): acceleration cost, joint
position and per-step velocity limits, the arm's spheres and the open hand (and a carried object, fixed
in the tool frame: the kinematic switch) clear of the fixtures and of the resting objects where the
graph-NLP put them, the arm clear of the trunk and of the other arm where that one stands meanwhile
(``motion.phases_of``: at its start posture while this arm acts). An idle arm's move home is optimised
too (``Transit.home``): straight, its fingers or what it holds can pass through a block. One call per arm
over all of its moves (the moves share no variable: each is its own NLP). The keyframes stay fixed: the
paper's own remedy for long plans ("fix the mode-switches and solve the trajectory of each step"), and a
solved graph-NLP stays solved.
A move the NLP cannot make feasible and no costlier keeps its straight motion; one the replay rejects
goes back to it (``validate_with_fallbacks``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import replace

import numpy as np
import pybullet as p

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.motion import Transit
from rlgp_exec.planning.nlp.hand import arm_link_spheres, body_obstacles, finger_spheres, other_arm_obstacles
from rlgp_exec.planning.nlp.path import Segment, optimize_paths
from rlgp_exec.planning.plan import Level3Stats
from rlgp_exec.planning.validate import Phase
from rlgp_exec.robot.pybullet_body import PyBulletRobot
from rlgp_exec.scene.geometry import object_box

__all__ = ["T_TRAJ", "Trajectories"]

log = logging.getLogger(__name__)
T_TRAJ = 20  # waypoints per move, ends (the straight motion's) included: the paper's


class Trajectories:
    """The trajectory stage of one planning call: the robot's shapes for the path NLP read once (from
    PyBullet at the start configuration), ``stats`` summed over the plans it optimises."""

    def __init__(self, lib: FactorLib, T: int = T_TRAJ) -> None:
        self.lib, self.T = lib, T
        model, q = lib.model, lib.q_nominal
        client = p.connect(p.DIRECT)
        try:
            robot = PyBulletRobot(model, client, collision_only=True)
            self.hand = finger_spheres(robot, model, q)
            # per arm: its spheres for the self-clearance rows, and what they clear (its trunk; the
            # other arms where they rest meanwhile)
            self.shapes = {
                arm: (arm_link_spheres(model, arm),
                      body_obstacles(robot, model, q, arm) + other_arm_obstacles(robot, model, q, arm))
                for arm in lib.arms
            }
        finally:
            p.disconnect(client)
        self.stats = Level3Stats()

    def _segment(self, phases: Sequence[Phase], t: Transit) -> Segment:
        lib = self.lib
        objects = tuple(replace(object_box(lib.objects[o]), T=lib.object_T(w)) for o, w in t.resting.items())
        held = None if t.held is None else (np.asarray(lib.objects[t.held[0]].size, float), t.held[1])
        warm = np.asarray(phases[t.phase].path[t.row:t.row + 2], float)
        return Segment(warm, tuple(lib.fixture_boxes) + objects, (), held, fix_base=True, strict=True)

    def optimise(self, phases: Sequence[Phase], transits: Sequence[Transit]) -> tuple[list[Phase], dict[int, Phase]]:
        """The phases with every arm's moves optimised (those whose NLP failed unchanged), and
        the original of each phase changed (the fallback for the replay). One move per arm and phase at
        most (``phases_of``'s). ``stats.acc_cost``: this plan's optimised moves (None if none was)."""
        out, originals = list(phases), dict[int, Phase]()
        done: list[tuple[Transit, np.ndarray]] = []  # (move, its optimised path (T, nq))
        acc: float | None = None
        warm_acc: float | None = None
        for arm in self.lib.arms:
            mine = [t for t in transits
                    if t.arm == arm and np.ptp(phases[t.phase].path[t.row:t.row + 2], axis=0).max() > 1e-9]
            if not mine:
                continue
            spheres, body = self.shapes[arm]
            res = optimize_paths(self.lib.model, [self._segment(phases, t) for t in mine], self.T, manipulator=arm,
                                 hand=self.hand, self_spheres=spheres, body=body)
            s = self.stats
            self.stats = replace(s, attempts=s.attempts + 1, solved=s.solved + res.ok,
                                 time_s=s.time_s + res.wall_s, jac_nnz=res.jac_nnz, n_var=res.n_var)
            log.info("trajectories of %s (%d moves, T = %d): %s, acceleration cost %.3g (straight %.3g), "
                     "%d iterations, %.2f s + %.2f s", arm, len(mine), self.T, res.reason, res.acc_cost,
                     res.warm_acc_cost, res.iterations, res.build_s, res.solve_s)
            for t, path, c, c0, ok in zip(mine, res.paths, res.acc_costs, res.warm_acc_costs, res.optimised,
                                          strict=True):
                if ok:  # a move whose NLP failed keeps its straight motion
                    acc, warm_acc = (acc or 0.0) + c, (warm_acc or 0.0) + c0
                    done.append((t, path))
        # last rows first: a phase's earlier moves keep their row indices
        for t, path in sorted(done, key=lambda tp: (tp[0].phase, tp[0].row), reverse=True):
            ph = out[t.phase]
            originals.setdefault(t.phase, phases[t.phase])
            out[t.phase] = replace(ph, path=np.vstack([ph.path[:t.row], path, ph.path[t.row + 2:]]))
        self.stats = replace(self.stats, acc_cost=acc, warm_acc_cost=warm_acc)
        return out, originals

    def kept(self, n_fallbacks: int, used: bool) -> None:
        """Count what the replay kept: ``n_fallbacks`` phases put back, and whether the plan passed with
        optimised moves in it."""
        s = self.stats
        self.stats = replace(s, fallbacks=s.fallbacks + n_fallbacks, used=s.used + used)
