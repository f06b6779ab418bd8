"""``--gui`` on a real X server (Xvfb): PyBullet's window opens, shows the scene framed as the overview,
plays the plan, and a key press in it ends the command with exit status 0. Needs Xvfb, xdotool and xwd
(Debian: xvfb, xdotool, x11-apps; `.ci/run` installs them where it can)."""

from __future__ import annotations

import os
import shutil
import struct
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
TOOLS = ("Xvfb", "xdotool", "xwd")
pytestmark = pytest.mark.skipif(
    not all(shutil.which(t) for t in TOOLS), reason=f"needs {', '.join(TOOLS)} (Debian: xvfb, xdotool, x11-apps)"
)


def _xvfb() -> tuple[subprocess.Popen, str]:
    r, w = os.pipe()
    proc = subprocess.Popen(["Xvfb", "-displayfd", str(w), "-screen", "0", "1280x1024x24", "-nolisten", "tcp"],
                            pass_fds=(w,), stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    os.close(w)
    with os.fdopen(r) as f:
        number = f.readline().strip()
    return proc, f":{number}"


def _screenshot(display: str) -> np.ndarray:
    """The root window (H, W, 3) through xwd (its XWD header, then 32-bit pixels)."""
    d = subprocess.run(["xwd", "-root", "-silent"], env={**os.environ, "DISPLAY": display}, capture_output=True,
                       check=True, timeout=30).stdout
    (header,), (w, h) = struct.unpack(">I", d[:4]), struct.unpack(">II", d[16:24])
    (ncolors,) = struct.unpack(">I", d[76:80])
    off = header + 12 * ncolors
    return np.frombuffer(d[off : off + w * h * 4], np.uint8).reshape(h, w, 4)[:, :, :3]


def test_gui_opens_the_window_plays_the_plan_and_a_key_closes_it(tmp_path):
    xvfb, display = _xvfb()
    env = {**os.environ, "DISPLAY": display, "OPENBLAS_NUM_THREADS": "1"}
    err = tmp_path / "stderr.txt"
    try:
        blank = _screenshot(display)
        with err.open("w") as f:
            cli = subprocess.Popen([sys.executable, "-m", "rlgp_exec", "plan", str(ROOT / "tests/data/shelf_hsr.toml"),
                                    "--gui"], env=env, stdout=subprocess.PIPE, stderr=f, text=True)
        try:
            end = time.monotonic() + 400
            while "gui: playing" not in err.read_text() and cli.poll() is None and time.monotonic() < end:
                time.sleep(0.5)
            assert cli.poll() is None, err.read_text()[-2000:]
            window = subprocess.run(["xdotool", "search", "--sync", "--name", "Bullet Physics"], env=env,
                                    capture_output=True, text=True, timeout=60, check=True).stdout.split()[0]
            time.sleep(3.0)  # a few frames of the motion
            shot = _screenshot(display)
            assert float(shot.std()) > 20 and float(blank.std()) < 1, "nothing drawn on the screen"
            assert cli.poll() is None  # the window holds at the end of the motion until asked
            subprocess.run(["xdotool", "windowfocus", "--sync", window], env=env, timeout=30, check=True)
            for key in ("keydown", "keyup"):
                subprocess.run(["xdotool", key, "Escape"], env=env, timeout=30, check=True)
                time.sleep(0.2)
            assert cli.wait(timeout=60) == 0, err.read_text()[-2000:]
            assert "replay: collision-free, goal met" in cli.stdout.read()  # type: ignore[union-attr]
        finally:
            if cli.poll() is None:
                cli.kill()
                cli.wait()
    finally:
        xvfb.terminate()
        xvfb.wait(timeout=30)
