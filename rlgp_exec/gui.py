"""``--gui``: the motion in PyBullet's own window, where a display exists.

The window shows the same world the headless renderer draws (``sim.world``), framed as its overview
picture, played in real time by a player of ``animate`` (a plan's timed trajectory or a recording); it stays
open until ``q`` or Esc is pressed in it (closing the window ends the process from inside PyBullet's X
client instead, exit status 1, after every output was written).
"""

from __future__ import annotations

import logging
import os
import socket
import time
from pathlib import Path

from rlgp_exec.errors import RlgpError

__all__ = ["require_display", "show_plan", "show_recording"]

log = logging.getLogger(__name__)


QUIT_KEYS = (ord("q"), 27)  # q, Esc
_NO_DISPLAY_HINT = "(render headless with plan/replay --animate FILE.gif|mp4, or use ssh -X / a desktop session)"


def _x_server_answers(display: str, timeout_s: float = 1.0) -> bool:
    """Whether the X server of ``display`` (``[host]:N[.S]``) accepts a connection: its unix socket for a local
    display, TCP port 6000 + N for a remote one. A display it cannot parse is left for PyBullet to try."""
    host, sep, rest = display.rpartition(":")
    number = rest.split(".")[0]
    if not sep or not number.isdigit():
        return True
    try:
        if host in ("", "unix"):
            with socket.socket(socket.AF_UNIX) as s:
                s.settimeout(timeout_s)
                s.connect(f"/tmp/.X11-unix/X{number}")
        else:
            socket.create_connection((host, 6000 + int(number)), timeout=timeout_s).close()
    except OSError:
        return False
    return True


def require_display() -> None:
    """Raise RlgpError (bad input: exit 2) where no X display is set or its server does not answer: PyBullet's
    GUI would print "cannot connect to X server" and end the process after the work was done."""
    display = os.environ.get("DISPLAY")
    if not display:
        raise RlgpError(f"--gui opens PyBullet's window and needs a display, but $DISPLAY is not set "
                        f"{_NO_DISPLAY_HINT}")
    if not _x_server_answers(display):
        raise RlgpError(f"--gui: no X server answers on DISPLAY={display} {_NO_DISPLAY_HINT}")


def _play(scene, make_player, hold: bool = True) -> None:
    # local: PyBullet (its import banner) and world.pybullet_world (OpenCV) load only to play
    import pybullet as p

    from rlgp_exec.world.pybullet_world import build_world

    require_display()
    cid = p.connect(p.GUI)
    if cid < 0:
        raise RlgpError(f"PyBullet could not open its window on display {os.environ.get('DISPLAY')!r}")
    try:
        p.configureDebugVisualizer(p.COV_ENABLE_GUI, 0, physicsClientId=cid)  # no side panels: the scene only
        world = build_world(scene, cid)
        duration, set_time = make_player(world)
        _frame(world)
        log.info("gui: playing %.1f s of motion; press q or Esc in the window to go on", duration)
        t0 = time.monotonic()
        while p.isConnected(cid):
            t = time.monotonic() - t0
            set_time(min(t, duration))
            if t >= duration and not hold:
                break
            keys = p.getKeyboardEvents(physicsClientId=cid)
            if any(k in keys and keys[k] & p.KEY_WAS_TRIGGERED for k in QUIT_KEYS):
                break
            time.sleep(1 / 30)
    except p.error:  # the window was closed mid-update
        pass
    finally:
        if p.isConnected(cid):
            p.disconnect(cid)


def _frame(world) -> None:
    """Point the window's camera as the overview picture is taken (``world.render``)."""
    # local: PyBullet (its import banner) and world.render load only to play
    import pybullet as p

    from rlgp_exec.world.render import overview_framing

    target, distance, yaw, pitch = overview_framing(world)
    p.resetDebugVisualizerCamera(distance, yaw, pitch, target, physicsClientId=world.client)


def show_plan(scene, timed, hold: bool = True) -> None:
    """Play a timed plan of ``scene`` in PyBullet's window."""
    # local: animate brings matplotlib and SciPy
    from rlgp_exec.animate import plan_player

    _play(scene, lambda world: (timed.duration_s, plan_player(world, timed)), hold)


def show_recording(path: str | Path, hold: bool = True) -> None:
    """Play a recording in PyBullet's window."""
    # local: animate and executive.replay bring matplotlib and SciPy
    from rlgp_exec.animate import recording_player
    from rlgp_exec.executive.replay import load_replay

    inp = load_replay(path)
    _play(inp.scene, lambda world: recording_player(world, inp), hold)
