"""``rlgp-exec replay FILE``: play a recording back into PyBullet.

The world is rebuilt from the recording's first ``/scene`` message; the robot follows the recorded
``/robot_state`` (measured joints and odometry) and the objects their recorded ``/detections``. The
replay reports what it saw — duration, base distance, transitions, the task results, collisions of the
replayed robot with the world — and can write a picture of the final state and of the base path.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from rlgp_exec.executive.recorder import RecordingError, read_recording
from rlgp_exec.executive.world import drawer_openings
from rlgp_exec.scene import scene_from_dict

__all__ = ["ReplayReport", "replay"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ReplayReport:
    path: Path
    complete: bool  # the recording was finished by its writer
    messages: int
    states: int
    duration_s: float
    base_distance_m: float
    transitions: tuple[str, ...]
    results: tuple[str, ...]
    collisions: tuple[str, ...]  # robot penetrations seen during the replay (body names)

    def text(self) -> str:
        lines = [
            f"{self.path}: {self.messages} messages{'' if self.complete else ' (unfinished: the writer was stopped)'}",
            f"  {self.states} robot states over {self.duration_s:.1f} s; base travelled {self.base_distance_m:.2f} m",
            "  transitions: " + (" -> ".join(self.transitions) or "none"),
        ]
        lines += [f"  result: {r}" for r in self.results]
        lines.append("  replay: " + ("no collisions" if not self.collisions else f"COLLISIONS {list(self.collisions)}"))
        return "\n".join(lines)


def replay(path: str | Path, png: str | Path | None = None, step: int = 5) -> ReplayReport:
    """Replay ``path`` (every ``step``-th robot state) into a DIRECT PyBullet world built from it."""
    from sim.world import build_world

    rec = read_recording(path)
    scenes = rec.topic("/scene")
    if not scenes:
        raise RecordingError(f"{path}: no /scene message: nothing to rebuild the world from")
    scene = scene_from_dict(scenes[0][1], f"{Path(path).name}:/scene")
    states = rec.topic("/robot_state")
    detections = rec.topic("/detections")
    transitions = tuple(d["to"] for _, d in rec.topic("/transitions"))
    results = tuple(
        f"{d.get('status')}: {d.get('detail')}" for _, d in rec.topic("/events") if d.get("kind") == "result"
    )
    world = build_world(scene, tags=False, collision_only=True)
    collisions: set[str] = set()
    dist = 0.0
    try:
        model = world.robot_model
        names = model.joint_names
        q = model.home(scene.robot.base, scene.robot.joints)
        objects = set(world.objects)
        fingers = {n for m in model.config.manipulators for n in model.manipulator(m.name).links}
        det_i = 0
        last_xy = None
        for k, (t, st) in enumerate(states):
            while det_i < len(detections) and detections[det_i][0] <= t:
                sensed = {n: np.asarray(T, float) for n, T in detections[det_i][1].get("poses", {}).items()}
                for name, T in sensed.items():
                    if name in world.objects:
                        world.set_object_pose(name, T)
                for cabinet, opening in drawer_openings(scene, sensed).items():  # drawers as sensed
                    world.set_drawer_opening(cabinet, float(np.clip(opening, 0.0, world.cabinets[cabinet].travel)))
                det_i += 1
            x, y, yaw = st["base"]
            if last_xy is not None:
                dist += math.hypot(x - last_xy[0], y - last_xy[1])
            last_xy = (x, y)
            if k % step and k != len(states) - 1:
                continue
            q = np.array(q, float)
            q[:3] = (x, y, yaw)
            by_name = dict(zip(st["names"], st["q"], strict=True))
            for i, n in enumerate(names[3:], start=3):
                if n in by_name:
                    q[i] = by_name[n]
            world.robot.set_q(q)
            for c in world.robot.contacts(5e-3):  # robot vs fixtures and itself (objects move in the hand)
                name = world.body_name(c.other_body) if c.other_body != world.robot.id else c.other_link
                if name in objects:
                    continue
                if c.link in fingers and name in world.cabinets and c.other_link == "0":
                    continue  # the fingers round a drawer's knob (link 0 of a cabinet: its drawer)
                collisions.add(f"robot {c.link} ~ {name}")
        if png is not None:
            import cv2

            from sim.render import render_world

            rgb = render_world(world, 960, 720, "overview")
            cv2.imwrite(str(png), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    finally:
        world.close()
    duration = states[-1][1]["stamp"] - states[0][1]["stamp"] if len(states) > 1 else 0.0  # robot clock
    return ReplayReport(
        Path(path),
        rec.complete,
        len(rec.messages),
        len(states),
        duration,
        dist,
        transitions,
        results,
        tuple(sorted(collisions)),
    )
