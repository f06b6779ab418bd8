"""The headless dry run behind ``make demo``: sense, plan and act on an HSR task, across a real process
and transport boundary.

The world: the scene file with its tagged objects moved up to 4 cm away (the file is wrong, as on a
real robot). Sense: the head camera looks around (rendered images, AprilTags, PnP, fusion) and the
perceived scene replaces the file's poses. Robot: ``sim-robot`` runs the true world in its own process
and speaks the HSR's Zenoh interface, its head camera (``rlgp_exec.sim.camera_node``) rendered in a process of
its own and published as ROS 2 images. Camera: the executive's camera source reads those images over
Zenoh, points the head at the task's objects and reports each one's error against the true world.
Executive: SENSE (the robot's state; object poses by the head camera: objects too small to detect from
where the robot stands planned unverified and checked when seen, drawers and what is inside them kept by
the hand; ``objects="mocap"`` senses the server's mocap stream, the simulation's truth, instead),
PLAN (R-LGP, validated by replay), TIME (TOPPRA), ACT (Ruckig at 100 Hz over Zenoh, monitored), VERIFY (the
goal literals on the sensed poses; the report gives each object's final error against the truth).
Everything is recorded to MCAP; the base path is plotted from the recording.

Each stage reports what it measured; the report's ``ok`` is False if any stage failed.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.scene import Scene, load_scene
from rlgp_exec.scene.serialize import scene_to_toml
from rlgp_exec.scene.shipped import resolve_scene, shipped_scene_dir
from rlgp_exec.sim.robot_process import RobotProcess

__all__ = ["DEMO_OBJECTS", "DEMO_SCENE", "DEMO_SCENES", "DemoReport", "Stage", "run_demo"]

log = logging.getLogger(__name__)

DEMO_SCENE = "table_clearing_hsr"  # the R-LGP paper's task: knob, drawer, cup against a wall, drops
DEMO_SCENES = ("table_clearing_hsr", "sorting_hsr")  # HSR scenes with tagged objects
PERTURB_M = 0.04  # [m] how far the true objects are from the file
DEMO_OBJECTS = "camera"  # the executive's object source, as on the robot; "mocap" senses the simulation's truth


def _against_truth(sensed: object, endpoint: str) -> str:
    """Each object of the executive's final (sensed) scene against the simulation's truth (its mocap
    stream, read for this only), in mm."""

    # local: executive.runner brings matplotlib and SciPy
    from rlgp_exec.executive.runner import RunOptions, connect

    assert isinstance(sensed, Scene)
    hal, mocap = connect(sensed, RunOptions(backend="zenoh", endpoint=endpoint, objects="mocap"))
    try:
        end = time.monotonic() + 3.0
        true = mocap.poses()
        while not true and time.monotonic() < end:
            time.sleep(0.05)
            true = mocap.poses()
    finally:
        mocap.close()
        hal.shutdown()
    errs = [
        f"{o.name} {np.linalg.norm(np.asarray(o.pose[:3]) - true[o.name][:3, 3]) * 1e3:.0f} mm from the truth"
        for o in sensed.objects
        if o.name in true
    ]
    return ", ".join(errs) if errs else "no truth to compare with"


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
    """Run one stage; its start and its result are logged as they happen (the CLI shows them)."""
    log.info("%s: started", name)
    t0 = time.perf_counter()
    try:
        detail = fn()
        report.stages.append(Stage(name, True, detail, time.perf_counter() - t0))
    except RlgpError as e:
        report.stages.append(Stage(name, False, str(e), time.perf_counter() - t0))
    s = report.stages[-1]
    log.info("%s: %s in %.1f s: %s", name, "ok" if s.ok else "FAILED", s.seconds, s.detail)
    return bool(s.ok)


def scene_path(name: str) -> Path:
    """A shipped scene file by name (``sim/scenes/<name>.toml``)."""
    path = shipped_scene_dir() / f"{name}.toml"
    if not path.is_file():
        raise RlgpError(f"no shipped scene {name!r} ({path})")
    return path


def _plot_base_path(recording: Path, out: Path) -> None:
    # local: matplotlib (~0.7 s) loads only when a plot is drawn
    import matplotlib

    matplotlib.use("Agg")
    # local: after matplotlib.use("Agg"), which must come first; executive.recorder brings matplotlib and SciPy
    import matplotlib.pyplot as plt

    from rlgp_exec.executive.recorder import read_recording

    rec = read_recording(recording)
    xy = [d["base"][:2] for _, d in rec.topic("/robot_state")]
    scenes = rec.topic("/scene")
    fig, ax = plt.subplots(figsize=(6, 6))
    if scenes:
        for f in scenes[0][1]["fixture"]:
            (x, y, _, _), (sx, sy, _) = f["pose"], f["size"]
            ax.add_patch(plt.Rectangle((x - sx / 2, y - sy / 2), sx, sy, color="0.8"))
        for o in scenes[-1][1]["object"]:
            ax.plot(o["pose"][0], o["pose"][1], "s", color=o["color"] if o["color"] != "wood" else "brown")
    if xy:
        xs, ys = zip(*xy, strict=True)
        ax.plot(xs, ys, "-", color="tab:blue", lw=1.5, label="base (odometry)")
        ax.plot(xs[0], ys[0], "o", color="tab:green", label="start")
        ax.plot(xs[-1], ys[-1], "x", color="tab:red", label="end")
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.legend(loc="best", fontsize=8)
    ax.set_title("base path (from the recording)")
    fig.savefig(out, dpi=100, bbox_inches="tight")
    plt.close(fig)


def run_demo(
    out: Path, seed: int = 0, scene_name: str = DEMO_SCENE, objects: str = DEMO_OBJECTS, foxglove: int | None = None
) -> DemoReport:
    """Run the dry run on an HSR scene with tagged objects (a shipped scene's name or a scene file, as
    ``scene.shipped.resolve_scene`` reads it); files go to ``out``; ``objects``: the executive's object
    source ("mocap" or "camera"); ``foxglove``: serve the execution live to Foxglove on that port."""
    if objects not in ("mocap", "camera"):
        raise RlgpError(f"demo objects {objects!r}: valid: ['mocap', 'camera']")
    # local: OpenCV (~0.25 s) loads only when the demo runs
    import cv2

    # local: world.pybullet_world and world.render bring OpenCV and Pinocchio
    from rlgp_exec.world.pybullet_world import build_world
    from rlgp_exec.world.render import render_world

    out.mkdir(parents=True, exist_ok=True)
    report = DemoReport(scene_name)
    state: dict[str, object] = {}

    def load() -> str:
        # local: perception.runner brings SciPy and OpenCV
        from rlgp_exec.perception.runner import perturbed_scene

        scene = load_scene(resolve_scene(scene_name))
        truth = perturbed_scene(scene, PERTURB_M, seed)
        path = out / "demo_world.toml"
        path.write_text(scene_to_toml(truth))
        state["scene"], state["truth"], state["truth_path"] = scene, truth, path
        goal = " ".join(map(str, scene.goal.literals))
        return f"{len(scene.fixtures)} fixtures, {len(scene.objects)} objects, goal {goal}"

    def pictures() -> str:
        w = build_world(state["truth"])  # type: ignore[arg-type]
        try:
            bad = w.penetrations()
            if bad:
                raise RlgpError(f"initial collisions: {bad}")
            for view in ("overview", "robot"):
                rgb = render_world(w, 960 if view == "overview" else 640, 720 if view == "overview" else 480, view)
                path = out / f"demo_{view}.png"
                cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
                report.files.append(path)
        finally:
            w.close()
        return "true world built (no collisions); overview and head-camera images rendered"

    def perceive() -> str:
        # local: perception.runner brings SciPy and OpenCV
        from rlgp_exec.perception.runner import perceive_scene

        res = perceive_scene(state["scene"], perturb_m=PERTURB_M, seed=seed)  # type: ignore[arg-type]
        if res.missing:
            raise RlgpError(f"not seen: {sorted(res.missing)}")
        state["perceived"] = res.scene
        errs = ", ".join(f"{n} {e:.1f} mm" for n, e in sorted(res.errors_mm.items()))
        return f"{res.views} views; objects {PERTURB_M * 100:.0f} cm off the file, found within {errs}"

    def robot() -> str:
        robot = RobotProcess(state["truth_path"], camera=True)  # type: ignore[arg-type]
        state["proc"], state["endpoint"] = robot, robot.endpoint
        return (
            f"sim-robot (pid {robot.pid}) serving the HSR's Zenoh interface on {robot.endpoint}, "
            f"its head camera from pid {robot.camera.pid if robot.camera else '-'}"
        )

    def camera() -> str:

        # local: executive.camera_source and executive.runner bring matplotlib and SciPy
        from rlgp_exec.executive.camera_source import CameraObjects
        from rlgp_exec.executive.runner import RunOptions, connect

        truth = state["truth"]
        hal, objects = connect(truth, RunOptions(backend="zenoh", endpoint=state["endpoint"], objects="camera"))  # type: ignore[arg-type]
        try:
            assert isinstance(objects, CameraObjects)
            tagged = sorted(o.name for o in truth.objects if o.tag is not None)  # type: ignore[attr-defined]
            found = objects.look_for(tagged, hal)
            poses = objects.poses()
            whys = dict(found.undetectable)
            lines = []
            for n in tagged:
                if n in poses:
                    e = np.linalg.norm(poses[n][:3, 3] - truth.object(n).T[:3, 3]) * 1e3  # type: ignore[attr-defined]
                    lines.append(f"{n} by camera {e:.1f} mm from the truth")
                else:
                    lines.append(f"{n} not seen ({whys.get(n, 'not in any view').removeprefix(n + ': ')})")
            end = time.monotonic() + 3.0  # look_for waits for no image when no view from here can place one
            while not objects.stats()["frames"] and time.monotonic() < end:
                time.sleep(0.05)
            st = objects.stats()
            # objects too far to place from the start are planned on the file's poses and verified on the way
            if not st["frames"]:
                raise RlgpError(f"no head camera image processed: {st['rejected'] or 'none received'}")
            if not poses and len(whys) < len(tagged):
                raise RlgpError(f"the head camera saw none of {tagged}: {found.detail}")
            head = f"by the head camera over Zenoh ({found.views} head views, {st['frames']} images)"
            return f"{head}: {'; '.join(lines)}"
        finally:
            objects.close()
            hal.shutdown()

    def execute() -> str:
        # local: executive.runner brings matplotlib and SciPy
        from rlgp_exec.executive.runner import RunOptions, run_task

        rec = out / "demo.mcap"
        opts = RunOptions(backend="zenoh", endpoint=state["endpoint"], record=rec, seed=seed, objects=objects,  # type: ignore[arg-type]
                          foxglove=foxglove)
        result, ex = run_task(state["perceived"], opts)  # type: ignore[arg-type]
        report.files.append(rec)
        state["recording"] = rec
        if objects == "mocap":
            how = "objects sensed by the mocap stream (the simulation's truth)"
        else:
            how = "objects sensed by the head camera"
            if ex.verified:
                how += "; planned unverified, then verified: " + ", ".join(f"{n} {w}" for n, w in ex.verified.items())
            if ex.unverified:
                how += f"; never verified: {sorted(ex.unverified)}"
        if not result.ok:
            raise RlgpError(f"{how}: {result.status.value}: {result.detail}")
        if objects == "camera":
            how += "; at the end " + _against_truth(ex.scene, state["endpoint"])  # type: ignore[arg-type]
        return (
            f"{how}; {' '.join(result.executed)}; planning {result.planning_time_s:.1f} s ({result.plans} plan(s), "
            f"{result.replans} replan(s)), first motion after {result.time_to_first_motion_s:.1f} s, execution "
            f"{result.execution_time_s:.1f} s, base travelled {result.base_distance_m:.1f} m; {result.detail}"
        )

    def plot() -> str:
        # local: executive.replay brings matplotlib and SciPy
        from rlgp_exec.executive.replay import replay

        png = out / "demo_base_path.png"
        _plot_base_path(state["recording"], png)  # type: ignore[arg-type]
        report.files.append(png)
        r = replay(state["recording"])  # type: ignore[arg-type]
        if r.collisions:
            raise RlgpError(f"the recording replays with collisions: {list(r.collisions)}")
        return f"recording replayed in PyBullet: {r.states} states, {r.duration_s:.1f} s, no collisions"

    try:
        for name, fn in (
            ("scene", load),
            ("world", pictures),
            ("perceive", perceive),
            ("robot", robot),
            ("camera", camera),
            ("executive", execute),
            ("replay", plot),
        ):
            if not _stage(report, name, fn):
                break
    finally:
        proc = state.get("proc")
        if proc is not None:
            proc.stop()  # type: ignore[attr-defined]
    return report
