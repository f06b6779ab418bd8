"""What a long command is doing, on stderr, as it happens (the CLI's display of the library's progress).

Library code logs its progress at INFO on its own loggers (the planners' candidates, a bench's runs, the
demo's stages); :func:`start` attaches one handler to those loggers and shows each record as it arrives:
on a terminal through ``rich`` (each line with its elapsed time, and a spinner naming the current stage
with its running time), elsewhere (CI, pipes, files) as plain timestamped lines, with a "still ..." line
after ``HEARTBEAT_S`` without news (a long motion reports nothing until it ends). stdout stays the command's.
The CLI's own steps (loading, rendering, writing) are :func:`stage` blocks.
"""

from __future__ import annotations

import contextlib
import logging
import sys
import threading
import time
from collections.abc import Iterator, Sequence
from typing import IO, Any

__all__ = ["Display", "current", "stage", "start", "stop"]

_current: list[Display] = []  # the display start() opened, until stop()
HEARTBEAT_S = 30.0  # [s] plain display: a "still ..." line after this long without a line
STAGE_SAY_S = 2.0  # [s] a stage's start is shown once it has run this long (or at its first line)


class _Handler(logging.Handler):
    def __init__(self, display: Display) -> None:
        super().__init__(logging.INFO)
        self.display = display

    def emit(self, record: logging.LogRecord) -> None:
        try:
            msg = record.getMessage()
            if record.levelno >= logging.WARNING:
                msg = f"{record.levelname}: {msg}"
            self.display.line(msg)
        except Exception:  # a display failure must never break the command
            self.handleError(record)


class _Spinner:
    """The rich renderable of the current stage: its text and running time, re-rendered at each refresh."""

    def __init__(self, text: str) -> None:
        self.text, self.t0 = text, time.monotonic()

    def __rich__(self) -> str:
        # local: rich loads only for a terminal's live display
        from rich.markup import escape

        return f"{escape(self.text)} [dim]({time.monotonic() - self.t0:.0f} s)[/dim]"


class Display:
    """Progress lines on ``stream``; ``rich`` when it is a terminal (or ``fancy`` says so)."""

    def __init__(self, stream: IO[str] | None = None, fancy: bool | None = None) -> None:
        self.stream = stream if stream is not None else sys.stderr
        isatty = getattr(self.stream, "isatty", None)
        self.fancy = bool(isatty and isatty()) if fancy is None else fancy
        self.t0 = time.monotonic()
        self.handler = _Handler(self)
        self.loggers: tuple[str, ...] = ()  # the loggers start() attached it to
        self._console: Any = None
        self._status: Any = None
        self._last = (self.t0, "")  # (time.monotonic(), message) of the last line
        self._lock = threading.Lock()
        self._closed = threading.Event()
        self._pending: tuple[str, float] | None = None  # the current stage's start line and time, until said
        if self.fancy:
            # local: rich loads only for a terminal's live display
            from rich.console import Console

            self._console = Console(file=self.stream, highlight=False)
        else:
            threading.Thread(target=self._heartbeat, name="progress-heartbeat", daemon=True).start()

    def _heartbeat(self) -> None:
        while not self._closed.wait(1.0):
            t, msg = self._last
            if msg and time.monotonic() - t >= HEARTBEAT_S:
                self._plain(f"still at: {msg} ({time.monotonic() - t:.0f} s)", keep=msg)

    def elapsed(self) -> float:
        return time.monotonic() - self.t0

    def line(self, msg: str) -> None:
        """One progress line, now (after the start of the stage it belongs to, if that is still unsaid)."""
        self._say_pending()
        self._emit(msg)

    def _say_pending(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, None
        if pending is not None:
            self._emit(*pending)

    def _emit(self, msg: str, at: float | None = None) -> None:
        """``msg`` stamped with ``at`` [s since the start] (default: now)."""
        if self._console is not None:
            # local: rich loads only for a terminal's live display
            from rich.markup import escape

            self._console.print(f"[dim]{self.elapsed() if at is None else at:7.1f} s[/dim]  {escape(msg)}")
        else:
            self._plain(msg, keep=msg, at=at)

    def _plain(self, text: str, keep: str, at: float | None = None) -> None:
        with self._lock:
            if self._closed.is_set():
                return
            t = self.elapsed() if at is None else at
            wall = time.strftime("%H:%M:%S", time.localtime(time.time() - (self.elapsed() - t)))
            self.stream.write(f"{wall} [{t:7.1f} s] {text}\n")
            self.stream.flush()
            self._last = (time.monotonic(), keep)

    @contextlib.contextmanager
    def stage(self, text: str) -> Iterator[None]:
        """A step of the command: its start (stamped when it started) once it has taken ``STAGE_SAY_S`` or
        says something (a step that ends at once, e.g. refusing bad input, leaves stderr to its one error
        line), and on a terminal a spinner while it runs."""
        self._say_pending()
        with self._lock:
            self._pending = (f"{text} ...", self.elapsed())
        timer = threading.Timer(STAGE_SAY_S, self._say_pending)
        timer.daemon = True
        timer.start()
        status = None
        if self._console is not None and self._status is None:  # a terminal, and not inside another stage
            status = self._status = self._console.status(_Spinner(text), spinner="dots")
            status.start()
        try:
            yield
        finally:
            timer.cancel()
            with self._lock:
                self._pending = None
            if status is not None:
                status.stop()
                self._status = None

    def close(self) -> None:
        with self._lock:
            self._closed.set()
        if self._status is not None:
            self._status.stop()
            self._status = None


def start(loggers: Sequence[str], stream: IO[str] | None = None, fancy: bool | None = None) -> Display:
    """Show the INFO records of ``loggers`` (and below them) on ``stream`` from now on, instead of the root
    handler's copy; replaces the display an earlier start() opened."""
    stop()
    display = Display(stream, fancy)
    root_level = logging.getLogger().getEffectiveLevel()
    for name in loggers:
        lg = logging.getLogger(name)
        lg.addHandler(display.handler)
        lg.setLevel(min(root_level, logging.INFO))
        lg.propagate = False
    display.loggers = tuple(loggers)
    _current.append(display)
    return display


def stop() -> None:
    """Detach the current display (its loggers back to propagating to the root handler)."""
    while _current:
        display = _current.pop()
        display.close()
        for name in display.loggers:
            lg = logging.getLogger(name)
            lg.removeHandler(display.handler)
            lg.propagate = True
            lg.setLevel(logging.NOTSET)


def current() -> Display | None:
    return _current[-1] if _current else None


@contextlib.contextmanager
def stage(text: str) -> Iterator[None]:
    """:meth:`Display.stage` on the current display; nothing when there is none (``-q``)."""
    d = current()
    if d is None:
        yield
        return
    with d.stage(text):
        yield
