"""The headless dry run behind ``make demo``: HSR table clearing, as far as this build goes.

Each stage that exists runs for real and reports what it measured; stages whose layer has not
landed are listed as such (never faked). The report's ``ok`` is False if any stage that ran failed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

from rlgp_exec.errors import RlgpError

__all__ = ["DemoReport", "Stage", "run_demo"]

log = logging.getLogger(__name__)

DEMO_SCENE = "table_clearing_hsr"


@dataclass
class Stage:
    name: str
    ok: bool | None  # None: not available in this build
    detail: str
    seconds: float = 0.0


@dataclass
class DemoReport:
    scene: str
    stages: list[Stage] = field(default_factory=list)
    files: list[Path] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return all(s.ok is not False for s in self.stages)

    def text(self) -> str:
        lines = [f"rlgp-exec demo: {self.scene} (HSR, headless PyBullet)"]
        for s in self.stages:
            mark = {True: "ok  ", False: "FAIL", None: "n/a "}[s.ok]
            lines.append(f"  [{mark}] {s.name:<12} {s.detail}" + (f"  ({s.seconds:.2f} s)" if s.ok is not None else ""))
        lines += [f"  wrote {f}" for f in self.files]
        lines.append("result: " + ("OK" if self.ok else "FAILED"))
        return "\n".join(lines)


def _stage(report: DemoReport, name: str, fn: Callable[[], str]) -> bool:
    t0 = time.perf_counter()
    try:
        detail = fn()
        report.stages.append(Stage(name, True, detail, time.perf_counter() - t0))
        return True
    except RlgpError as e:
        report.stages.append(Stage(name, False, str(e), time.perf_counter() - t0))
        return False


def scene_path(name: str) -> Path:
    """A shipped scene file by name (``sim/scenes/<name>.toml``)."""
    import sim

    path = Path(sim.__file__).resolve().parent / "scenes" / f"{name}.toml"
    if not path.is_file():
        raise RlgpError(f"no shipped scene {name!r} ({path})")
    return path


def run_demo(out: Path, seed: int = 0) -> DemoReport:
    """Run every stage this build has on the HSR table-clearing scene; files go to ``out``."""
    import cv2

    from rlgp_exec.scene import load_scene, randomize
    from sim.render import render_world
    from sim.world import build_world

    out.mkdir(parents=True, exist_ok=True)
    report = DemoReport(DEMO_SCENE)
    state: dict[str, object] = {}

    def load() -> str:
        scene = randomize(load_scene(scene_path(DEMO_SCENE)), seed)
        state["scene"] = scene
        goal = " ".join(map(str, scene.goal.literals))
        return f"{len(scene.fixtures)} fixtures, {len(scene.objects)} objects, goal {goal}"

    def world() -> str:
        w = build_world(state["scene"])  # type: ignore[arg-type]
        state["world"] = w
        bad = w.penetrations()
        if bad:
            raise RlgpError(f"initial collisions: {bad}")
        return f"built; no initial collisions; robot q = {w.robot_model.nq} joints"

    def pictures() -> str:
        w = state["world"]
        for view in ("overview", "robot"):
            rgb = render_world(w, 960 if view == "overview" else 640, 720 if view == "overview" else 480, view)  # type: ignore[arg-type]
            path = out / f"demo_{view}.png"
            cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
            report.files.append(path)
        return "overview and head-camera images rendered"

    try:
        for name, fn in (("scene", load), ("world", world), ("render", pictures)):
            if not _stage(report, name, fn):
                break
    finally:
        w = state.get("world")
        if w is not None:
            w.close()  # type: ignore[attr-defined]
    for name, issue in (("perceive", "issue 8"), ("plan", "issues 3-5"), ("time", "issue 6"),
                        ("execute", "issues 7, 9")):
        if not any(s.name == name for s in report.stages):
            report.stages.append(Stage(name, None, f"not in this build ({issue})"))
    return report
