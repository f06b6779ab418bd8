"""12 — Table clearing with a drawer, HSR: take_knob, open_drawer, pick, drop, take_knob, close_drawer
(R-LGP paper, Sec. V-C: 17 s, 6 steps, 9 m travelled).

Perceive, plan, replay in the true world: ``rlgp_exec.perceive_plan``; exit 0 when every plan holds.

    .venv/bin/python tools/12_table_clearing_hsr.py [--planners rlgp] [--seed N] [--perturb M] [--json FILE]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlgp_exec.cli import task_script

if __name__ == "__main__":
    sys.exit(task_script(__doc__, "table_clearing_hsr", "rlgp"))
