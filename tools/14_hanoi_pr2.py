"""14 — Towers of Hanoi with two arms, PR2 (GNPP paper, Sec. VIII, Table I). Only the top disc's tag is
visible in the stack: the discs below keep their file poses (and the world is not perturbed).

Perceive, plan, replay in the true world: ``rlgp_exec.perceive_plan``; exit 0 when every plan holds.

    .venv/bin/python tools/14_hanoi_pr2.py [--planners gnpp] [--seed N] [--perturb M] [--json FILE]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlgp_exec.cli import task_script

if __name__ == "__main__":
    sys.exit(task_script(__doc__, "hanoi_pr2", "gnpp", perturb_m=0.0))
