"""The motion as a GIF or MP4: a plan's timed trajectory (``plan --animate``) or a recording
(``replay --animate``), rendered frame by frame with PyBullet's renderer (``sim.render``) and written with
imageio. A held object rides with the hand, a drawer follows the hand on its knob, as in the plan's replay.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

from rlgp_exec.errors import RlgpError
from rlgp_exec.planning.drawer_replay import DrawerMotion
from rlgp_exec.planning.drawers import drawer_views
from rlgp_exec.timing.samples import PlanSamples

__all__ = [
    "FORMATS",
    "VIDEO_S",
    "FrameFn",
    "animate_plan",
    "animate_recording",
    "auto_speed",
    "check_animation_path",
    "plan_player",
    "recording_player",
]

log = logging.getLogger(__name__)
FORMATS = (".gif", ".mp4")
FrameFn = Callable[[float], None]  # put the world in its state at t [s]
VIDEO_S = 30.0  # [s] the video's length when no speed is given: long motions play faster


def check_animation_path(path: str | Path) -> Path:
    """``path`` if it names a .gif or .mp4 file (before any work is done: bad input fails at once)."""
    out = Path(path)
    if out.suffix.lower() not in FORMATS:
        raise RlgpError(f"--animate {out}: the file must end in {' or '.join(FORMATS)}")
    if out.is_dir():
        raise RlgpError(f"--animate {out}: is a directory")
    return out


def auto_speed(duration_s: float, speed: float | None) -> float:
    """``speed`` (x real time), or the speed that fits the motion in about ``VIDEO_S`` of video (at least 1)."""
    return max(1.0, duration_s / VIDEO_S) if speed is None else speed


def _frame_times(duration_s: float, fps: float, speed: float) -> Iterator[float]:
    if not (fps > 0 and speed > 0):
        raise RlgpError(f"animation fps {fps} and speed {speed}: both must be positive")
    n = max(1, int(np.ceil(duration_s / speed * fps)))
    for i in range(n + 1):
        yield min(duration_s, i * speed / fps)


def _write(world, out: Path, duration_s: float, set_time: FrameFn, fps: float, speed: float | None,
           size: tuple[int, int], view: str) -> Path:
    # local: imageio loads only for --animate; world.render brings OpenCV
    import imageio.v2 as imageio

    from rlgp_exec.world.render import camera, render_world

    out.parent.mkdir(parents=True, exist_ok=True)
    speed = auto_speed(duration_s, speed)
    times = list(_frame_times(duration_s, fps, speed))
    kw: dict[str, Any] = (
        {"duration": 1.0 / fps, "loop": 0} if out.suffix.lower() == ".gif" else {"fps": fps, "macro_block_size": 1}
    )
    log.info("animation: %d frames (%.1f s of motion at %.3gx) to %s", len(times), duration_s, speed, out)
    set_time(0.0)
    cam = None if view == "robot" else camera(world, size[0], size[1], view)  # framed once, on the start
    try:
        with imageio.get_writer(out, **kw) as writer:
            for i, t in enumerate(times):
                set_time(t)
                writer.append_data(render_world(world, size[0], size[1], view, cam))  # type: ignore[attr-defined]
                if i and i % 50 == 0:
                    log.info("animation: frame %d/%d (t = %.1f s)", i, len(times), t)
    except (OSError, ValueError, RuntimeError) as e:  # imageio's writers: unwritable path, codec errors
        raise RlgpError(f"cannot write the animation {out}: {e}") from e
    return out


def plan_player(world, timed: PlanSamples) -> FrameFn:
    """A function putting ``world`` (built from the plan's scene) in the plan's state at t [s]; call it with
    non-decreasing times (the grasps and drawer motions happen in order)."""
    model = world.robot_model
    state: dict = {"phase": -1, "grip": None, "drawer": (None, None)}

    def tool(arm: str | None, q) -> np.ndarray:
        return model.fk(q, model.manipulator(arm).tool_frame)

    def enter_phase(k: int, q_start) -> None:
        prev = timed.phases[k - 1] if k > 0 else None
        ph = timed.phases[k]
        if prev is not None and prev.grasp is not None:  # grasped at the previous phase's end
            T_tool_obj = np.linalg.solve(tool(prev.arm, q_start), world.object_pose(prev.grasp))
            state["grip"] = (prev.grasp, prev.arm, T_tool_obj)
        if (prev is not None and prev.release is not None) or ph.held is None:
            state["grip"] = None
        drawer = None
        if ph.drives_drawer:
            cab = _cabinet_at_hand(world, tool(ph.arm, q_start))
            if cab is not None:
                drawer = DrawerMotion.start(world, cab, tool(ph.arm, q_start))
        state["drawer"], state["phase"] = (drawer, ph.arm), k

    def set_time(t: float) -> None:
        i = int(np.clip(np.searchsorted(timed.t, t), 0, len(timed.t) - 1))
        q = timed.q[i]
        k = int(timed.phase[i])
        while state["phase"] < k:
            nxt = state["phase"] + 1
            enter_phase(nxt, timed.q[max(i - 1, 0)] if nxt == k else q)
        world.robot.set_q(q)
        grip = state["grip"]
        if grip is not None:
            name, arm, T_tool_obj = grip
            world.set_object_pose(name, tool(arm, q) @ T_tool_obj)
        drawer, arm = state["drawer"]
        if drawer is not None:
            drawer.follow(world, tool(arm, q))

    return set_time


def animate_plan(scene, timed: PlanSamples, out: str | Path, fps: float = 10.0, speed: float | None = None,
                 size: tuple[int, int] = (400, 300), view: str = "overview") -> Path:
    """Render ``timed`` (a plan of ``scene``) at ``fps`` frames per second of video, ``speed`` times real time."""
    # local: world.pybullet_world brings OpenCV
    from rlgp_exec.world.pybullet_world import build_world

    out = check_animation_path(out)
    world = build_world(scene)
    try:
        return _write(world, out, timed.duration_s, plan_player(world, timed), fps, speed, size, view)
    finally:
        world.close()


def _cabinet_at_hand(world, T_world_tool: np.ndarray) -> str | None:
    """The cabinet whose drawer knob is nearest the hand (the one a drawer phase drives)."""
    views = drawer_views(world.scene)
    if not views:
        return None
    p = T_world_tool[:3, 3]
    return min(views, key=lambda c: float(np.linalg.norm(views[c].T_world_knob(world.drawer_opening(c))[:3, 3] - p)))


def recording_player(world, inp) -> tuple[float, FrameFn]:
    """(duration [s] on the robot's clock, a function putting ``world`` in the recording's state at t [s])
    for a checked recording ``inp`` (``replay.load_replay``)."""
    # local: executive.world brings OpenCV and Foxglove
    from rlgp_exec.executive.world import drawer_openings

    states = inp.states
    if not states:
        raise RlgpError(f"{inp.recording.path}: no /robot_state messages: no motion to show")
    model = world.robot_model
    q_home = model.home(inp.scene.robot.base, inp.scene.robot.joints)
    rel = np.array([s.stamp for s in states]) - states[0].stamp
    det_t = np.array([t for t, _ in inp.detections])

    def set_time(t: float) -> None:
        st = states[int(np.clip(np.searchsorted(rel, t), 0, len(states) - 1))]
        n_det = int(np.searchsorted(det_t, st.t, side="right")) if len(det_t) else 0
        if n_det:
            sensed = inp.detections[n_det - 1][1]
            for name, T in sensed.items():
                if name in world.objects:
                    world.set_object_pose(name, T)
            for cabinet, opening in drawer_openings(inp.scene, sensed).items():
                world.set_drawer_opening(cabinet, float(np.clip(opening, 0.0, world.cabinets[cabinet].travel)))
        q = np.array(q_home, float)
        q[:3] = st.base
        for i, n in enumerate(model.joint_names[3:], start=3):
            if n in st.joints:
                q[i] = st.joints[n]
        world.robot.set_q(q)

    return float(rel[-1]), set_time


def animate_recording(path: str | Path, out: str | Path, fps: float = 10.0, speed: float | None = None,
                      size: tuple[int, int] = (400, 300), view: str = "overview") -> Path:
    """Render a recording's robot states and sensed object poses (``replay --animate``)."""
    # local: executive.replay and world.pybullet_world bring OpenCV and Foxglove
    from rlgp_exec.executive.replay import load_replay
    from rlgp_exec.world.pybullet_world import build_world

    out = check_animation_path(out)
    inp = load_replay(path)
    world = build_world(inp.scene)
    try:
        duration, set_time = recording_player(world, inp)
        return _write(world, out, duration, set_time, fps, speed, size, view)
    finally:
        world.close()
