"""Silence C-level chatter: PyBullet's URDF importer warnings on stdout around a block, its build banner on
stderr at import."""

from __future__ import annotations

import contextlib
import importlib
import os
import sys
from collections.abc import Iterator

__all__ = ["import_quietly", "quiet_stderr", "quiet_stdout"]


@contextlib.contextmanager
def _quiet(stream_name: str) -> Iterator[None]:
    """Redirect the file descriptor of ``sys.<stream_name>`` to /dev/null inside the block (the Python
    stream is flushed first)."""
    stream = getattr(sys, stream_name)
    try:
        fd = stream.fileno()
    except (AttributeError, OSError, ValueError):  # the stream replaced (pytest capture, notebooks)
        yield
        return
    stream.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        stream.flush()
        os.dup2(saved, fd)
        os.close(saved)


def quiet_stdout() -> contextlib.AbstractContextManager[None]:
    """Redirect file descriptor 1 to /dev/null inside the block (Python's sys.stdout is flushed first)."""
    return _quiet("stdout")


def quiet_stderr() -> contextlib.AbstractContextManager[None]:
    """Redirect file descriptor 2 to /dev/null inside the block (Python's sys.stderr is flushed first)."""
    return _quiet("stderr")


def import_quietly(module: str) -> None:
    """Import ``module`` with C-level stdout and stderr silenced (PyBullet prints its build time on import);
    an import error is raised as usual, its message kept. Later imports find it in ``sys.modules``."""
    if module in sys.modules:
        return

    with quiet_stdout(), quiet_stderr():
        importlib.import_module(module)
