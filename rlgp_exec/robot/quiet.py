"""Silence C-level chatter: PyBullet's URDF importer warnings on stdout around a block, its build banner on
stderr at import."""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator

__all__ = ["import_quietly", "quiet_stderr", "quiet_stdout"]


@contextlib.contextmanager
def quiet_stdout() -> Iterator[None]:
    """Redirect file descriptor 1 to /dev/null inside the block (Python's sys.stdout is flushed first)."""
    try:
        fd = sys.stdout.fileno()
    except (AttributeError, OSError, ValueError):  # stdout replaced (pytest capture, notebooks)
        yield
        return
    sys.stdout.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        sys.stdout.flush()
        os.dup2(saved, fd)
        os.close(saved)


@contextlib.contextmanager
def quiet_stderr() -> Iterator[None]:
    """Redirect file descriptor 2 to /dev/null inside the block (Python's sys.stderr is flushed first)."""
    try:
        fd = sys.stderr.fileno()
    except (AttributeError, OSError, ValueError):  # stderr replaced (pytest capture, notebooks)
        yield
        return
    sys.stderr.flush()
    saved = os.dup(fd)
    try:
        with open(os.devnull, "w") as devnull:
            os.dup2(devnull.fileno(), fd)
            yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, fd)
        os.close(saved)


def import_quietly(module: str) -> None:
    """Import ``module`` with C-level stdout and stderr silenced (PyBullet prints its build time on import);
    an import error is raised as usual, its message kept. Later imports find it in ``sys.modules``."""
    if module in sys.modules:
        return
    import importlib

    with quiet_stdout(), quiet_stderr():
        importlib.import_module(module)
