"""15 — Tower building behind obstacles that must be moved first, PR2 (GNPP paper, Sec. VIII and App. D).
The two obstacles stand 2 cm apart: by default only the objects' yaw is off the file (up to 0.3 rad).

Perceive, plan, replay in the true world: ``rlgp_exec.perceive_plan``; exit 0 when every plan holds.

    .venv/bin/python tools/15_obstacles_tower_pr2.py [--planners gnpp] [--seed N] [--perturb M] [--json FILE]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlgp_exec.cli import task_script

if __name__ == "__main__":
    sys.exit(task_script(__doc__, "obstacles_tower_pr2", "gnpp", perturb_m=0.0))
