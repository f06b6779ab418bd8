"""``rlgp-exec replay FILE``: play a recording back into PyBullet.

The world is rebuilt from the recording's first ``/scene`` message; the robot follows the recorded
``/robot_state`` (measured joints and odometry) and the objects their recorded ``/detections``. The
replay reports what it saw — duration, base distance, transitions, the task results, collisions of the
replayed robot with the world — and can write a picture of the final state and of the base path.

:func:`load_replay` reads and checks everything the replay uses before PyBullet sees any of it: a
recording cut off anywhere replays what it holds, and a malformed message is a :class:`RecordingError`
naming the file, the message's offset and the field.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.executive.recorder import Recording, RecordingError, read_recording
from rlgp_exec.executive.world import drawer_openings
from rlgp_exec.scene import Scene, scene_from_dict
from rlgp_exec.world.pybullet_world import build_world
from rlgp_exec.world.render import render_world

__all__ = ["ReplayInput", "ReplayReport", "ReplayState", "load_replay", "replay"]

log = logging.getLogger(__name__)

BOUND = 1e4  # [m, rad] no replayed coordinate or joint value is larger (PyBullet's broadphase is not for 1e300)


@dataclass(frozen=True)
class ReplayState:
    """One recorded /robot_state, checked."""

    t: float  # [s] wall time of the record
    stamp: float  # [s] the robot's clock
    base: tuple[float, float, float]  # x, y, yaw
    joints: dict[str, float]


@dataclass(frozen=True)
class ReplayInput:
    """What a replay plays, checked."""

    recording: Recording
    scene: Scene
    states: tuple[ReplayState, ...]
    detections: tuple[tuple[float, dict[str, np.ndarray]], ...]  # (t [s], object/frame: 4x4 pose)
    transitions: tuple[str, ...]
    results: tuple[str, ...]


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
    ending: str = "complete"  # how the file ends (Recording.ending)
    truncated_at: int | None = None  # [bytes] where an unfinished recording's complete records end

    def text(self) -> str:
        lines = [
            f"{self.path}: {self.messages} messages" + ("" if self.complete else f" ({self.ending})"),
            f"  {self.states} robot states over {self.duration_s:.1f} s; base travelled {self.base_distance_m:.2f} m",
            "  transitions: " + (" -> ".join(self.transitions) or "none"),
        ]
        lines += [f"  result: {r}" for r in self.results]
        lines.append("  replay: " + ("no collisions" if not self.collisions else f"COLLISIONS {list(self.collisions)}"))
        return "\n".join(lines)


def _number(where: str, field: str, v: Any, bound: float = BOUND) -> float:
    try:
        x = float(v) if isinstance(v, int | float) and not isinstance(v, bool) else math.nan
    except OverflowError:  # a JSON integer beyond a float
        x = math.nan
    if not (math.isfinite(x) and abs(x) <= bound):
        size = f" of at most {bound:g} in size" if math.isfinite(bound) else ""
        raise RecordingError(f"{where}: {field}: expected a finite number{size}, got {v!r:.80}")
    return x


def _numbers(where: str, field: str, v: Any, n: int | None = None) -> list[float]:
    if not isinstance(v, list) or (n is not None and len(v) != n):
        raise RecordingError(f"{where}: {field}: expected a list of {n if n is not None else 'some'} numbers, "
                             f"got {v!r:.80}")
    return [_number(where, f"{field}[{i}]", x) for i, x in enumerate(v)]


def _field(where: str, d: dict[str, Any], key: str) -> Any:
    if key not in d:
        raise RecordingError(f"{where}: missing field {key!r} (has {sorted(d)[:12]})")
    return d[key]


def _state(where: str, t: float, d: dict[str, Any]) -> ReplayState:
    names = _field(where, d, "names")
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise RecordingError(f"{where}: names: expected a list of joint names, got {names!r:.80}")
    q = _numbers(where, "q", _field(where, d, "q"), len(names))
    x, y, yaw = _numbers(where, "base", _field(where, d, "base"), 3)
    stamp = _number(where, "stamp", _field(where, d, "stamp"), math.inf)
    return ReplayState(t, stamp, (x, y, yaw), dict(zip(names, q, strict=True)))


def _poses(where: str, d: dict[str, Any]) -> dict[str, np.ndarray]:
    poses = d.get("poses", {})
    if not isinstance(poses, dict):
        raise RecordingError(f"{where}: poses: expected an object of 4x4 poses, got {poses!r:.80}")
    out = {}
    for name, T in poses.items():
        rows = T if isinstance(T, list) and len(T) == 4 else None
        if rows is None or not all(isinstance(r, list) and len(r) == 4 for r in rows):
            raise RecordingError(f"{where}: poses[{name!r}]: expected a 4x4 matrix, got {T!r:.80}")
        out[name] = np.array([_numbers(where, f"poses[{name!r}][{i}]", r, 4) for i, r in enumerate(rows)])
    return out


def load_replay(path: str | Path) -> ReplayInput:
    """Read ``path`` and check every message the replay uses (RecordingError naming the first bad one)."""
    rec = read_recording(path)
    by_topic: dict[str, list[tuple[str, float, dict[str, Any]]]] = {}
    for i, (topic, t, d) in enumerate(rec.messages):
        by_topic.setdefault(topic, []).append((rec.where(i), t, d))
    scenes = by_topic.get("/scene", [])
    if not scenes:
        raise RecordingError(
            f"{rec.path}: no /scene message ({len(rec.messages)} messages, {rec.ending}): "
            "nothing to rebuild the world from"
        )
    scene = scene_from_dict(scenes[0][2], scenes[0][0])
    states = tuple(_state(w, t, d) for w, t, d in by_topic.get("/robot_state", []))
    detections = tuple((t, _poses(w, d)) for w, t, d in by_topic.get("/detections", []))
    transitions = []
    for w, _, d in by_topic.get("/transitions", []):
        to = _field(w, d, "to")
        if not isinstance(to, str):
            raise RecordingError(f"{w}: to: expected a state name, got {to!r:.80}")
        transitions.append(to)
    results = tuple(
        f"{d.get('status')}: {d.get('detail')}" for _, _, d in by_topic.get("/events", []) if d.get("kind") == "result"
    )
    return ReplayInput(rec, scene, states, detections, tuple(transitions), results)


def replay(path: str | Path, png: str | Path | None = None, step: int = 5) -> ReplayReport:
    """Replay ``path`` (every ``step``-th robot state) into a DIRECT PyBullet world built from it."""
    inp = load_replay(path)
    scene, states, detections = inp.scene, inp.states, inp.detections
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
        for k, st in enumerate(states):
            while det_i < len(detections) and detections[det_i][0] <= st.t:
                sensed = detections[det_i][1]
                for name, T in sensed.items():
                    if name in world.objects:
                        world.set_object_pose(name, T)
                for cabinet, opening in drawer_openings(scene, sensed).items():  # drawers as sensed
                    world.set_drawer_opening(cabinet, float(np.clip(opening, 0.0, world.cabinets[cabinet].travel)))
                det_i += 1
            x, y, yaw = st.base
            if last_xy is not None:
                dist += math.hypot(x - last_xy[0], y - last_xy[1])
            last_xy = (x, y)
            if k % step and k != len(states) - 1:
                continue
            q = np.array(q, float)
            q[:3] = (x, y, yaw)
            for i, n in enumerate(names[3:], start=3):
                if n in st.joints:
                    q[i] = st.joints[n]
            world.robot.set_q(q)
            for c in world.robot.contacts(5e-3):  # robot vs fixtures and itself (objects move in the hand)
                name = world.body_name(c.other_body) if c.other_body != world.robot.id else c.other_link
                if name in objects:
                    continue
                if c.link in fingers and name in world.cabinets and c.other_link == "0":
                    continue  # the fingers round a drawer's knob (link 0 of a cabinet: its drawer)
                collisions.add(f"robot {c.link} ~ {name}")
        if png is not None:
            rgb = render_world(world, 960, 720, "overview")
            if not cv2.imwrite(str(png), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR)):
                raise RlgpError(f"cannot write the replay's picture {png} (a .png in an existing directory?)")
    finally:
        world.close()
    duration = states[-1].stamp - states[0].stamp if len(states) > 1 else 0.0  # robot clock
    rec = inp.recording
    return ReplayReport(
        Path(path),
        rec.complete,
        len(rec.messages),
        len(states),
        duration,
        dist,
        inp.transitions,
        inp.results,
        tuple(sorted(collisions)),
        rec.ending,
        rec.truncated_at,
    )
