"""``RobotProcess``: a ``sim-robot`` server in its own process over Zenoh on a free loopback port — what
the demo, the benchmarks, the tests and the tools talk to (a real process and transport boundary) — and,
with ``camera=True``, its head camera (``rlgp_exec.sim.camera_node``) in a second process."""

from __future__ import annotations

import logging
import os
import signal
import socket
import subprocess
import sys
import threading
from collections import deque
from pathlib import Path
from typing import IO

from rlgp_exec.errors import RlgpError

__all__ = ["RobotProcess", "camera_command", "free_endpoint"]

ROOT = Path(__file__).resolve().parents[1]
KEEP_LINES = 200  # of each child's output, for the error that reports its death

log = logging.getLogger(__name__)


def free_endpoint() -> str:
    """``tcp/127.0.0.1:<port>`` with a port free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


def camera_command(robot: str, scene: str | Path, endpoint: str, namespace: str = "", jpeg: bool = False) -> list[str]:
    """The command line of the camera node of the robot server at ``endpoint``."""
    cmd = [sys.executable, "-m", "rlgp_exec.sim.camera_node", "--robot", robot, "--scene", str(scene)]
    cmd += ["--endpoint", endpoint]
    if namespace:
        cmd += ["--namespace", namespace]
    return cmd + (["--jpeg"] if jpeg else [])


def _wait_ready(proc: subprocess.Popen[str], what: str) -> str:
    line = proc.stdout.readline() if proc.stdout else ""
    if "ready" not in line:
        err = proc.stderr.read() if proc.poll() is not None and proc.stderr else ""
        raise RlgpError(f"{what} did not start: {line.strip()} {err.strip()}")
    return line.strip()


def _drain(stream: IO[str], what: str, keep: deque[str]) -> None:
    """Read a child's output to its end: a pipe nobody reads fills (64 KiB) and blocks the child's next
    log line, which stops a robot or a camera mid-task. Its warnings become ours; the rest is debug."""
    for line in stream:
        line = line.rstrip()
        keep.append(line)
        if line.startswith(("WARNING", "ERROR", "CRITICAL", "Traceback")):
            log.warning("%s: %s", what, line)
        else:
            log.debug("%s: %s", what, line)


class RobotProcess:
    """Start ``python -m rlgp_exec.sim.robot_server --transport zenoh`` and wait for it to say it is ready; with
    ``camera``, then its camera node (the scene is needed: the camera renders it)."""

    def __init__(
        self,
        scene: str | Path | None = None,
        robot: str = "hsr",
        endpoint: str | None = None,
        camera: bool = False,
        jpeg: bool = False,
    ) -> None:
        if camera and scene is None:
            raise RlgpError("RobotProcess(camera=True) needs the scene the camera renders")
        self.endpoint = endpoint or free_endpoint()
        self.camera: subprocess.Popen[str] | None = None
        cmd = [
            sys.executable,
            "-m",
            "rlgp_exec.sim.robot_server",
            "--robot",
            robot,
            "--transport",
            "zenoh",
            "--endpoint",
            self.endpoint,
        ]
        if scene is not None:
            cmd += ["--scene", str(scene)]
        #: the last KEEP_LINES lines each child wrote ("sim-robot", "camera node")
        self.output: dict[str, deque[str]] = {}
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            self.ready_line = _wait_ready(self.proc, "sim-robot")
            self._drain(self.proc, "sim-robot")
            if camera:
                assert scene is not None
                self.camera = subprocess.Popen(
                    camera_command(robot, scene, self.endpoint, jpeg=jpeg),
                    cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                )
                _wait_ready(self.camera, "the camera node")
                self._drain(self.camera, "camera node")
        except BaseException:
            self.stop()
            raise

    def _drain(self, proc: subprocess.Popen[str], what: str) -> None:
        keep = self.output.setdefault(what, deque(maxlen=KEEP_LINES))
        for stream in (proc.stdout, proc.stderr):
            if stream is not None:
                threading.Thread(target=_drain, args=(stream, what, keep), name=f"{what} output", daemon=True).start()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL: the robot vanishes mid-whatever."""
        os.kill(self.proc.pid, signal.SIGKILL)

    def stop(self, timeout: float = 10.0) -> None:
        for proc in (self.camera, self.proc):
            if proc is not None and proc.poll() is None:
                proc.terminate()
                try:
                    proc.wait(timeout)
                except subprocess.TimeoutExpired:
                    proc.kill()
                    proc.wait(timeout)

    def __enter__(self) -> RobotProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
