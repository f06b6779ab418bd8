"""From a feasible graph-NLP to joint paths the executive can run (and the replay can check).

The keyframes are the solved arm configurations at each action. Between them each action is one
phase of straight joint-space segments: every arm left at a keyframe first lifts its hand
``LIFT`` straight up (IK, posture kept); every other arm then returns to its start posture (one that
holds an object takes it along); the acting arm moves to ``LIFT`` above its keyframe, then down onto
it (grasp or release). This is not the
paper's 20-waypoint trajectory optimisation: the replay (``validate_plan``) decides.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.guess import TopIK
from rlgp_exec.planning.gnpp.pntc import Var
from rlgp_exec.planning.symbolic.model import GroundAction
from rlgp_exec.planning.validate import Phase
from rlgp_exec.robot.model import FloatArray

__all__ = ["LIFT", "phases_of"]

LIFT = 0.10  # [m]


def _lift(lib: FactorLib, ik: TopIK, arm: str, q7: FloatArray) -> FloatArray | None:
    pos = lib.tool_T(arm, q7)[:3, 3] + np.array([0.0, 0.0, LIFT])
    ok, q = ik.solve(arm, pos, q7)
    return q if ok else None


def phases_of(
    lib: FactorLib, ik: TopIK, actions: Sequence[GroundAction], values: Mapping[Var, FloatArray]
) -> tuple[tuple[Phase, ...], FloatArray] | str:
    """(phases, keyframes (n, nq)) or the reason no path could be laid out."""
    arms = lib.arms
    cur = {m: lib.home_q(m) for m in arms}
    low = dict.fromkeys(arms, False)
    holding: dict[str, str] = {}
    phases: list[Phase] = []
    keyframes = []

    def full() -> FloatArray:
        return lib.full_q(cur)

    def lift_low(path: list[FloatArray], active: str | None, where: str) -> str | None:
        """Raise every arm left down at its last keyframe (appending to ``path``); with an ``active`` arm
        about to act, the other idle arms also go home. The reason on failure."""
        for arm in arms:
            if low[arm]:
                up = _lift(lib, ik, arm, cur[arm])
                if up is None:
                    return f"cannot lift {arm} after {where}"
                cur[arm] = up
                path.append(full())
                low[arm] = False
            if active is not None and arm != active and not np.array_equal(cur[arm], lib.home_q(arm)):
                # out of the active arm's way, with what it holds: the graph-NLP kept the arms apart
                # at the keyframes only, not along the approach
                cur[arm] = lib.home_q(arm)
                path.append(full())
        return None

    for k, a in enumerate(actions):
        m, obj = a.args[0], a.args[1]
        v = Var("q", m, k + 1)
        if v not in values:
            return f"no keyframe for {a}"
        path = [full()]
        why = lift_low(path, m, f"its last action (before {a})")
        if why is not None:
            return why
        q_k = values[v]
        pre = _lift(lib, ik, m, q_k)
        if pre is None:
            return f"no approach {LIFT} m above the keyframe of {a}"
        cur[m] = pre
        path.append(full())
        cur[m] = q_k
        path.append(full())
        keyframes.append(full())
        low[m] = True
        carried = tuple((arm, o) for arm, o in holding.items() if arm != m)
        if a.name == "pick":
            phases.append(Phase(np.array(path), None, grasp=obj, arm=m, carried=carried))
            holding[m] = obj
        else:
            phases.append(Phase(np.array(path), obj, release=obj, arm=m, carried=carried))
            holding.pop(m, None)
    path = [full()]
    why = lift_low(path, None, "the last action")
    if why is not None:
        return why
    carried = tuple(holding.items())
    phases.append(Phase(np.array(path), None, carried=carried))
    return tuple(phases), np.array(keyframes).reshape(len(keyframes), -1)
