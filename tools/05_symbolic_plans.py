"""Symbolic plans for every shipped scene, from our best-first search and from Fast Downward.

    .venv/bin/python tools/05_symbolic_plans.py [--scene NAME] [--search lama-first|optimal] [--gnpp]

For each scene: the grounding size; the first plan of ``best_first`` with unit costs (A* with the
admissible goal bound) and with the distance-only baseline cost; Fast Downward on the lifted
domain (``--search``, default lama-first) and on the ground copy with ``optimal`` (astar(lmcut())).
With ``--gnpp`` it also forbids the first step of the plan (as a minimal infeasible subgraph
``<s_0, s_1>``) and shows the alternative both planners find. Times are wall-clock.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.planning.symbolic import (  # noqa: E402
    ForbiddenSequence,
    PartialState,
    best_first,
    distance_cost,
    goal_lower_bound,
    ground,
    problem_from_scene,
    reformulate,
    solve_ground,
    solve_spec,
)
from rlgp_exec.scene import load_scene  # noqa: E402


def show(label: str, actions, seconds: float, extra: str = "") -> None:
    print(f"  {label:<24} {len(actions):>2} actions  {seconds * 1000:7.1f} ms  {extra}")
    print("      " + " ".join(str(a) for a in actions))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scene", help="one scene name (default: all in sim/scenes)")
    ap.add_argument("--search", default="lama-first", help="Fast Downward search for the lifted run")
    ap.add_argument("--gnpp", action="store_true", help="also forbid the first step and replan")
    args = ap.parse_args()
    logging.basicConfig(level=logging.WARNING)
    paths = sorted((ROOT / "sim" / "scenes").glob("*.toml"))
    if args.scene:
        paths = [p for p in paths if p.stem == args.scene]
        if not paths:
            valid = [p.stem for p in sorted((ROOT / "sim" / "scenes").glob("*.toml"))]
            print(f"unknown scene {args.scene!r}; valid: {valid}")
            return 2
    failures = 0
    for path in paths:
        scene = load_scene(path)
        t = time.perf_counter()
        spec = problem_from_scene(scene)
        g = ground(spec)
        t_ground = time.perf_counter() - t
        print(
            f"\n== {scene.name} ({scene.robot.name}): {len(g.operators)} ground actions, "
            f"grounded in {t_ground * 1000:.1f} ms; goal {' '.join(str(lit) for lit in scene.goal.literals)}"
        )
        h = goal_lower_bound(g)
        for label, kw in (("best_first unit A*", {}), ("best_first distance", {"cost_fn": distance_cost(scene)})):
            t = time.perf_counter()
            it = best_first(g, max_expansions=100_000, heuristic=h, **kw)
            plan = next(it, None)
            dt = time.perf_counter() - t
            if plan is None:
                print(f"  {label}: no plan ({it.stats})")
                failures += 1
                continue
            ok = g.reaches_goal(plan.actions)
            failures += not ok
            show(label, plan.actions, dt, f"cost {plan.cost:.2f}, {it.stats.expanded} expanded, reaches goal: {ok}")
        for label, run in (
            (f"FD lifted {args.search}", lambda spec=spec: solve_spec(spec, search=args.search)),
            ("FD ground optimal", lambda g=g: solve_ground(g, search="optimal")),
        ):
            r = run()
            if not r.solved:
                print(f"  {label}: {r.status.value} ({r.reason})")
                failures += 1
                continue
            ok = g.reaches_goal(r.plan)
            failures += not ok
            show(label, r.plan, r.wall_time_s, f"reaches goal: {ok}")
        if args.gnpp and plan is not None:
            forbid = ForbiddenSequence(
                (PartialState(plan.states[0]), PartialState.of([a for a in plan.states[1] - plan.states[0]]))
            )
            ref = reformulate(g, [forbid])
            r = solve_ground(ref.problem)
            print(f"  GNPP: forbid {plan.actions[0]} from the start ->")
            if r.solved:
                show("FD reformulated", r.plan, r.wall_time_s, f"reaches goal: {g.reaches_goal(r.plan)}")
            else:
                print(f"  FD reformulated: {r.status.value} ({r.reason})")
            t = time.perf_counter()
            alt = next(best_first(ref.problem, heuristic=h), None)
            if alt is not None:
                show("best_first reformulated", alt.actions, time.perf_counter() - t)
    print(f"\n{len(paths)} scenes, {failures} failures")
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
