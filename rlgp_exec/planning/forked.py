"""Independent pieces of one plan on the machine's other core: ``fork_map(fn, items)`` calls ``fn`` on
every item, half of them in a forked child process (a copy of this one: nothing is rebuilt or sent
there), and returns the results in the items' order, as a plain loop would.

Used where one plan has independent numeric work that is not thread-safe to share (IPOPT's MUMPS
serialises its calls across threads): level 3's segments. A result is a flat dict of numbers, strings
and numpy arrays; the child's come back through a pipe as one JSON header and the arrays' raw bytes
(no pickle). A child that fails, dies or does not answer within the timeout is killed and its items are
done here instead, so the answer never depends on the child. The active budget (``planning.budget``) is
shared: while the child runs, each process may spend half of what is left (the child's CPU time reaches
the parent's clock only once it has finished). POSIX only (``os.fork``); elsewhere, or
with ``workers`` < 2, the loop runs here.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import select
import signal
import struct
import time
from collections.abc import Callable, Sequence
from typing import TypeVar

import numpy as np

from rlgp_exec.planning import budget

__all__ = ["Result", "decode", "encode", "fork_map"]

log = logging.getLogger(__name__)
Item = TypeVar("Item")
Value = float | int | str | bool | None | np.ndarray
Result = dict[str, Value]
MIN_TIMEOUT_S = 30.0  # [s] the child gets at least this long, and 5x what this process's own half took


def encode(results: list[Result]) -> bytes:
    """Results as one frame: 8-byte header length, a JSON header (arrays as dtype, shape and offset), the
    arrays' bytes."""
    header, chunks, offset = [], [], 0
    for res in results:
        entry: dict[str, object] = {}
        for key, v in res.items():
            if isinstance(v, np.ndarray):
                a = np.ascontiguousarray(v)
                entry[key] = {"dtype": a.dtype.str, "shape": list(a.shape), "offset": offset}
                chunks.append(a.tobytes())
                offset += a.nbytes
            elif v is None or isinstance(v, (bool, int, float, str)):
                entry[key] = {"value": v}
            else:
                raise TypeError(f"fork_map result {key!r}: {type(v).__name__}; valid: numbers, str, None, ndarray")
        header.append(entry)
    head = json.dumps(header).encode()
    return struct.pack("<Q", len(head)) + head + b"".join(chunks)


def decode(frame: bytes) -> list[Result]:
    """``encode``'s inverse; raises ValueError on a frame that is not one."""
    if len(frame) < 8:
        raise ValueError(f"fork_map frame of {len(frame)} bytes: shorter than its header length")
    (n,) = struct.unpack("<Q", frame[:8])
    try:
        header = json.loads(frame[8:8 + n].decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise ValueError(f"fork_map frame header: {e}") from None
    body = memoryview(frame)[8 + n:]
    out: list[Result] = []
    for entry in header:
        res: Result = {}
        for key, spec in entry.items():
            if "value" in spec:
                res[key] = spec["value"]
                continue
            dtype, shape, offset = np.dtype(spec["dtype"]), tuple(spec["shape"]), int(spec["offset"])
            size = int(np.prod(shape)) * dtype.itemsize
            if offset + size > len(body):
                raise ValueError(f"fork_map frame: array {key!r} runs past the frame's end")
            res[key] = np.frombuffer(body[offset:offset + size], dtype=dtype).reshape(shape).copy()
        out.append(res)
    return out


def _read_all(fd: int, deadline: float) -> bytes | None:
    """Everything written to ``fd`` until its end, or None when ``deadline`` (perf_counter [s]) passes."""
    chunks: list[bytes] = []
    while True:
        left = deadline - time.perf_counter()
        if left <= 0.0:
            return None
        ready, _, _ = select.select([fd], [], [], left)
        if not ready:
            return None
        chunk = os.read(fd, 1 << 16)
        if not chunk:
            return b"".join(chunks)
        chunks.append(chunk)


def fork_map(fn: Callable[[Item], Result], items: Sequence[Item], workers: int = 2) -> list[Result]:
    """``[fn(x) for x in items]``, the odd-numbered items in a forked child when ``workers`` >= 2."""
    if workers < 2 or len(items) < 2 or not hasattr(os, "fork"):
        return [fn(x) for x in items]
    with budget.shared(2):
        return _forked(fn, items)


def _forked(fn: Callable[[Item], Result], items: Sequence[Item]) -> list[Result]:
    """``fork_map`` with two processes (the active budget already shared)."""
    b = budget.active()
    theirs = list(range(1, len(items), 2))
    read_fd, write_fd = os.pipe()
    clock = budget.cpu_clock()
    pid = os.fork()
    if pid == 0:  # the child: its items, one frame, and out without the parent's exit handlers
        code = 0
        try:
            os.close(read_fd)
            if b is not None:
                b.forked(clock)
            frame = encode([fn(items[k]) for k in theirs])
        except BaseException:  # whatever it was, the parent does these items itself
            frame, code = b"", 1
        try:
            view = memoryview(frame)
            while view:
                view = view[os.write(write_fd, view):]
        finally:
            os._exit(code)
    os.close(write_fd)
    got: list[Result] | None = None
    try:
        t0 = time.perf_counter()
        mine = {k: fn(items[k]) for k in range(0, len(items), 2)}
        answer = _read_all(read_fd, time.perf_counter() + max(MIN_TIMEOUT_S, 5.0 * (time.perf_counter() - t0)))
        if answer is None:
            log.warning("fork_map: the child did not answer in time; its %d items are done here", len(theirs))
        elif answer:
            got = decode(answer)
        else:
            log.warning("fork_map: the child failed; its %d items are done here", len(theirs))
    except ValueError as e:
        log.warning("fork_map: the child's answer is unreadable (%s); its items are done here", e)
    finally:
        os.close(read_fd)
        if got is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
    if got is None or len(got) != len(theirs):
        got = [fn(items[k]) for k in theirs]
    mine.update(zip(theirs, got, strict=True))
    return [mine[k] for k in range(len(items))]
