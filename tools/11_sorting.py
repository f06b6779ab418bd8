"""11 — Sorting by colour on large tables, some objects reachable from one side only (R-LGP paper, Sec. V-B:
R-LGP 2 s and 100 %; the distance-only LGP baseline 50 %). ``--robot pr2|hsr``.

Perceive, plan, replay in the true world: ``rlgp_exec.perceive_plan``; exit 0 when every plan holds.

    .venv/bin/python tools/11_sorting.py [--planners rlgp,lgp] [--seed N] [--perturb M] [--json FILE]
"""

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from rlgp_exec.cli import task_script

if __name__ == "__main__":
    sys.exit(task_script(__doc__, "sorting_{robot}", "rlgp,lgp", robots=("pr2", "hsr")))
