"""13 — Tower building with two 7-DoF arms, PR2 (GNPP paper, Sec. VIII, Table I: 2-20 s).

Perceive, plan, replay in the true world: ``rlgp_exec.perceive_plan``; exit 0 when every plan holds.

    .venv/bin/python tools/13_tower_pr2.py [--planners gnpp] [--seed N] [--perturb M] [--json FILE]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlgp_exec.cli import task_script

if __name__ == "__main__":
    sys.exit(task_script(__doc__, "tower_pr2", "gnpp"))
