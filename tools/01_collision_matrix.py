"""01 — Self-collision matrix of a robot, the way MoveIt's setup assistant builds one.

Samples random configurations and reports link pairs that collide at the home pose ("default")
and in nearly every sample ("always"); such pairs are artefacts of the collision geometry
(convex hulls of neighbouring links) rather than real collisions, and belong in
robots/<robot>/robot.toml [collision].allowed. Pairs colliding only sometimes are real and must
stay checked.

    python tools/01_collision_matrix.py pr2 --samples 1000
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np
import pybullet as p

from rlgp_exec.robot.model import load_robot
from rlgp_exec.robot.pybullet_body import PyBulletRobot


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("robot", choices=["hsr", "pr2"])
    ap.add_argument("--samples", type=int, default=1000)
    ap.add_argument("--always", type=float, default=0.95, help="fraction of samples that makes a pair 'always'")
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    model = load_robot(args.robot)
    client = p.connect(p.DIRECT)
    body = PyBulletRobot(model, client)
    home = {tuple(sorted((c.link, c.other_link))) for c in body.contacts() if c.is_self}
    rng = np.random.default_rng(args.seed)
    counts: Counter[tuple[str, str]] = Counter()
    for _ in range(args.samples):
        body.set_q(model.random_q(rng))
        counts.update({tuple(sorted((c.link, c.other_link))) for c in body.contacts() if c.is_self})
    always = sorted(k for k, n in counts.items() if n >= args.always * args.samples)
    print(f"# {args.robot}: {args.samples} samples; already allowed: {len(body.allowed_pairs)} pairs")
    print("# colliding at home (default):")
    for a, b in sorted(home):
        print(f'  ["{a}", "{b}"],')
    print(f"# colliding in >= {args.always:.0%} of samples (always):")
    for a, b in always:
        print(f'  ["{a}", "{b}"],  # {counts[(a, b)] / args.samples:.0%}')
    print("# most frequent remaining pairs (checked):")
    for (a, b), n in counts.most_common(15):
        if (a, b) not in always:
            print(f"  {a} ~ {b}: {n / args.samples:.0%}")


if __name__ == "__main__":
    main()
