"""GNPP on a scene (PR2, or field_hsr: the mobile HSR): the conflicts it learns, the plan it finds, and what it cost.

    .venv/bin/python tools/06_gnpp.py [SCENE] [--variant gnpp_trn] [--logic internal|fd] [--blocks N]
                                      [--timeout S] [--seed K]

SCENE defaults to sim/scenes/tower_pr2.toml; ``--blocks N`` keeps the first N goal literals (and only
the objects they name, plus any object that is not in the goal) for a quick run. Prints every learnt
conflict (its factors and the partial-state sequence forbidden in the logic task), then the result:
status, actions, N0 / N / NLP counts, time split between logic and NLPs, and the replay verdict.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.planning.gnpp import VARIANTS, Logic, plan_gnpp  # noqa: E402
from rlgp_exec.scene import load_scene, randomize  # noqa: E402


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("scene", nargs="?", default=str(ROOT / "sim" / "scenes" / "tower_pr2.toml"))
    ap.add_argument("--variant", default="gnpp_trn", choices=list(VARIANTS))
    ap.add_argument("--logic", default="internal", choices=[x.value for x in Logic])
    ap.add_argument("--blocks", type=int, default=0, help="keep only the first N goal literals")
    ap.add_argument("--timeout", type=float, default=60.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("-v", "--verbose", action="store_true")
    args = ap.parse_args()
    logging.basicConfig(level=logging.INFO if args.verbose else logging.WARNING, format="%(name)s: %(message)s")

    scene = load_scene(args.scene)
    if args.seed:
        scene = randomize(scene, args.seed)
    if args.blocks:
        goal = scene.goal.literals[: args.blocks]
        named = {a for lit in goal for a in lit.args}
        in_goal = {a for lit in scene.goal.literals for a in lit.args}
        objects = tuple(o for o in scene.objects if o.name in named or o.name not in in_goal)
        scene = dataclasses.replace(scene, objects=objects, goal=dataclasses.replace(scene.goal, literals=goal))
    print(f"{scene.name}: {len(scene.objects)} objects, goal {' '.join(str(g) for g in scene.goal.literals)}")

    res = plan_gnpp(scene, args.variant, logic=Logic(args.logic), timeout_s=args.timeout)
    for k, (c, seq) in enumerate(zip(res.conflict_factors, res.conflicts, strict=False)):
        print(f"conflict {k} ({c.relaxation}, {len(c.factors)} factors): {c}")
        print("    forbidden: " + " -> ".join(str(p) for p in seq.states))
    plan, c = res.plan, res.counters
    print(f"\nstatus {res.status.value}: {plan.reason}")
    print("actions: " + " ".join(plan.actions))
    print(
        f"N0 {c['n0']}  N {c['n']}  NLPs {c['nlp']}  conflicts {c['conflicts']}  blocked plans {c['blocked_plans']}  "
        f"iterations {c['iterations']}  database hits {c['db_hits']}"
    )
    print(f"time {plan.planning_time_s:.2f} s (logic {c['logic_s']:.2f} s, NLPs {c['nlp_s']:.2f} s)")
    if plan.validation is not None:
        v = plan.validation
        print(f"replay: collision-free {v.collision_free}, goal met {v.goal_met}")
    return 0 if plan.success else 1


if __name__ == "__main__":
    sys.exit(main())
