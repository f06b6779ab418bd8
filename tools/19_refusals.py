"""19 — how fast impossible tasks are refused: each refusal rule on a scene made for it, through the
planners' own entry points (``plan_scene``, ``plan_gnpp``), and ``rlgp-exec plan`` end to end.

    .venv/bin/python tools/19_refusals.py [--cli]

Printed per case: the planner, the wall time of the call [s] and the first 120 characters of the
refusal (or "ACCEPTED", which for these cases is a defect).
"""

from __future__ import annotations

import argparse
import dataclasses
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.planning.capabilities import TaskRefusedError  # noqa: E402
from rlgp_exec.planning.gnpp.planner import plan_gnpp  # noqa: E402
from rlgp_exec.planning.rlgp import plan_scene  # noqa: E402
from rlgp_exec.scene import Scene, load_scene  # noqa: E402

SCENES = ROOT / "sim" / "scenes"


def _resized(scene: Scene, name: str, size: tuple[float, float, float]) -> Scene:
    """The object resized, its bottom kept on its support."""
    def one(o):
        z = o.pose[2] - (o.size[2] - size[2]) / 2
        return dataclasses.replace(o, size=size, pose=(*o.pose[:2], z, o.pose[3]))

    return dataclasses.replace(scene, objects=tuple(one(o) if o.name == name else o for o in scene.objects))


def cases() -> list[tuple[str, str, Scene]]:
    pick = load_scene(SCENES / "pick_place_pr2.toml")
    block = pick.goal.literals[0].args[0]
    size = pick.object(block).size
    return [
        ("drawer task, GNPP", "gnpp_trn", load_scene(SCENES / "table_clearing_hsr.toml")),
        ("stacking task, R-LGP", "rlgp", load_scene(SCENES / "tower_pr2.toml")),
        ("out of reach, GNPP on the PR2", "gnpp_trn", load_scene(SCENES / "sorting_pr2.toml")),
        ("wider than the gripper", "rlgp", _resized(pick, block, (0.10, 0.12, size[2]))),
        ("shorter than the grasp", "rlgp", _resized(pick, block, (size[0], size[1], 0.012))),
        ("1 micron wide", "rlgp", _resized(pick, block, (1e-6, 1e-6, size[2]))),
    ]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cli", action="store_true", help="also time `rlgp-exec plan` on a refused scene file")
    args = ap.parse_args()
    bad = 0
    for what, planner, scene in cases():
        t0 = time.perf_counter()
        try:
            if planner.startswith("gnpp"):
                plan_gnpp(scene, planner)
            else:
                plan_scene(scene, planner)
            text, bad = "ACCEPTED", bad + 1
        except TaskRefusedError as e:
            text = str(e)
        print(f"{what:32s} {planner:9s} {time.perf_counter() - t0:6.3f} s  {text[:120]}")
    if args.cli:
        t0 = time.perf_counter()
        out = subprocess.run([sys.executable, "-m", "rlgp_exec", "plan", str(SCENES / "table_clearing_hsr.toml"),
                              "--planner", "gnpp"], capture_output=True, text=True, cwd=ROOT)
        line = (out.stderr.strip().splitlines() or [""])[-1]
        print(f"rlgp-exec plan (gnpp, drawer) exit {out.returncode} in {time.perf_counter() - t0:.2f} s: {line[:120]}")
        bad += out.returncode != 2
    return 1 if bad else 0


if __name__ == "__main__":
    sys.exit(main())
