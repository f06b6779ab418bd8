"""``RobotProcess``: a ``sim-robot`` server in its own process over Zenoh on a free loopback port — what
the demo, the benchmarks, the tests and the tools talk to (a real process and transport boundary)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
from pathlib import Path

from rlgp_exec.errors import RlgpError

__all__ = ["RobotProcess", "free_endpoint"]

ROOT = Path(__file__).resolve().parents[1]


def free_endpoint() -> str:
    """``tcp/127.0.0.1:<port>`` with a port free right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return f"tcp/127.0.0.1:{s.getsockname()[1]}"


class RobotProcess:
    """Start ``python -m sim.robot_server --transport zenoh`` and wait for it to say it is ready."""

    def __init__(self, scene: str | Path | None = None, robot: str = "hsr", endpoint: str | None = None) -> None:
        self.endpoint = endpoint or free_endpoint()
        cmd = [
            sys.executable,
            "-m",
            "sim.robot_server",
            "--robot",
            robot,
            "--transport",
            "zenoh",
            "--endpoint",
            self.endpoint,
        ]
        if scene is not None:
            cmd += ["--scene", str(scene)]
        self.proc = subprocess.Popen(cmd, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        line = self.proc.stdout.readline() if self.proc.stdout else ""
        if "ready" not in line:
            err = self.proc.stderr.read() if self.proc.poll() is not None and self.proc.stderr else ""
            self.stop()
            raise RlgpError(f"sim-robot did not start: {line.strip()} {err.strip()}")
        self.ready_line = line.strip()

    @property
    def pid(self) -> int:
        return self.proc.pid

    def alive(self) -> bool:
        return self.proc.poll() is None

    def kill(self) -> None:
        """SIGKILL: the robot vanishes mid-whatever."""
        os.kill(self.proc.pid, signal.SIGKILL)

    def stop(self, timeout: float = 10.0) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(timeout)

    def __enter__(self) -> RobotProcess:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
