"""10 — Pick-and-place, PR2: three blocks from a table onto a tray (R-LGP paper, Sec. V-A: R-LGP 100 %
success, 10x shorter base path and 6x faster than PDDLStream).

Perceive, plan, replay in the true world: ``rlgp_exec.perceive_plan``; exit 0 when every plan holds.

    .venv/bin/python tools/10_pick_place_pr2.py [--planners rlgp,lgp] [--seed N] [--perturb M] [--json FILE]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlgp_exec.cli import task_script

if __name__ == "__main__":
    sys.exit(task_script(__doc__, "pick_place_pr2", "rlgp,lgp"))
