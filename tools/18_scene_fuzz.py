"""18 — fuzz `rlgp-exec plan` with mutants of the shipped scene files: every one must end with exit 0
(still a valid task, planned), 1 (the task failed) or 2 (refused with a short message), never a traceback,
a hang or a memory blow-up.

    .venv/bin/python tools/18_scene_fuzz.py [--count 1000] [--seed 0] [--timeout 105] [--jobs 1]
        [--planner rlgp] [--keep DIR] [--json FILE] [FILE ...]

The mutants come from ``rlgp_exec.scene.mutate`` (structural and value mutations of sim/scenes/*.toml:
deleted keys and tables, type swaps, extreme numbers, NaN/inf, scaled values, huge strings, deep nesting,
copied tables, swapped values; truncation, flipped bytes, deleted lines), fixed by ``--seed``; files given
on the command line run first, unmutated. Each runs as ``python -m rlgp_exec plan FILE`` in its own
process group under RLIMIT_AS = 2 GiB, killed after ``--timeout`` [s] of wall time (a hang). A hang is
filed under "load" when the file does not load in this process within 10 s, else under "planning".

Printed: cases, exit-code counts, tracebacks, hangs (load / planning), error messages of 500 characters or
more, the longest message, the largest peak RSS, the longest wall and CPU time, and every bad case.
"""

from __future__ import annotations

import argparse
import collections
import contextlib
import json
import os
import resource
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from rlgp_exec.errors import SceneError  # noqa: E402
from rlgp_exec.scene import load_scene  # noqa: E402
from rlgp_exec.scene.mutate import mutants  # noqa: E402

MEMORY_LIMIT = 2 << 30  # [bytes] RLIMIT_AS of each run
MESSAGE_LIMIT = 500  # [characters] an error message at least this long is a failure
PREFIX = "rlgp-exec plan: error: "
LOAD_CHECK_S = 10  # [s] the in-process load that tells a load hang from a planning hang


def _limit_memory() -> None:
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run_case(path: Path, timeout: float, planner: str) -> dict[str, Any]:
    """One ``rlgp-exec plan`` run: exit code, wall and CPU time, peak RSS, its error message, traceback?"""
    env = dict(os.environ, PYTHONPATH=str(ROOT), OPENBLAS_NUM_THREADS="1")
    t0 = time.monotonic()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(
            [sys.executable, "-m", "rlgp_exec", "plan", str(path), "--planner", planner],
            stdout=out, stderr=err, env=env, cwd=ROOT, preexec_fn=_limit_memory, start_new_session=True,
        )
        hang = False
        while True:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                break
            if time.monotonic() - t0 > timeout:
                hang = True
                os.killpg(proc.pid, signal.SIGKILL)
                pid, status, usage = os.wait4(proc.pid, 0)
                break
            time.sleep(0.02)
        proc.returncode = os.waitstatus_to_exitcode(status)  # reaped here: Popen must not wait again
        wall = time.monotonic() - t0
        with contextlib.suppress(ProcessLookupError):  # workers left behind by the run (its group)
            os.killpg(proc.pid, signal.SIGKILL)
        err.seek(0)
        stderr = err.read().decode("utf-8", "replace")
    errors = [ln[len(PREFIX):] for ln in stderr.splitlines() if ln.startswith(PREFIX)]
    return {
        "rc": None if hang else proc.returncode,
        "hang": hang,
        "wall_s": round(wall, 3),
        "cpu_s": round(usage.ru_utime + usage.ru_stime, 3),
        "max_rss_mb": round(usage.ru_maxrss / 1024, 1),
        "traceback": "Traceback (most recent call last)" in stderr,
        "message": errors[-1] if errors else "",
        "message_len": max((len(e) for e in errors), default=0),
        "stderr_tail": stderr[-400:],
    }


def loads_in_process(path: Path) -> str:
    """'loads', 'refused' or 'hangs' (no answer within LOAD_CHECK_S)."""

    def alarm(*_: Any) -> None:
        raise TimeoutError

    old = signal.signal(signal.SIGALRM, alarm)
    signal.alarm(LOAD_CHECK_S)
    try:
        load_scene(path)
        return "loads"
    except SceneError:
        return "refused"
    except TimeoutError:
        return "hangs"
    finally:
        signal.alarm(0)
        signal.signal(signal.SIGALRM, old)


def bad(case: dict[str, Any]) -> list[str]:
    """What is wrong with one run's outcome (empty: fine)."""
    why = []
    if case["hang"]:
        why.append(f"hang ({case['hang_in']})")
    elif case["rc"] not in (0, 1, 2):
        why.append(f"exit {case['rc']}")
    if case["traceback"]:
        why.append("traceback")
    if case["message_len"] >= MESSAGE_LIMIT:
        why.append(f"message of {case['message_len']} characters")
    if case["rc"] == 2 and not case["message"]:
        why.append("exit 2 without an error message")
    return why


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("files", nargs="*", type=Path, help="scene files to run first, as they are")
    ap.add_argument("--count", type=int, default=1000, help="mutants")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=105.0,
                    help="[s] wall time before a run counts as a hang (the planners' 100 s CPU budget + 5 s)")
    ap.add_argument("--jobs", type=int, default=1, help="runs at a time")
    ap.add_argument("--planner", default="rlgp")
    ap.add_argument("--keep", type=Path, help="write the mutants here (default: a temporary folder)")
    ap.add_argument("--json", type=Path, help="write every case and the summary here")
    args = ap.parse_args()

    sources = [(p.name, p.read_bytes()) for p in sorted((ROOT / "sim" / "scenes").glob("*.toml"))]
    folder = args.keep or Path(tempfile.mkdtemp(prefix="scene_fuzz_"))
    folder.mkdir(parents=True, exist_ok=True)
    cases: list[tuple[str, Path]] = [(f"file:{p.name}", p.resolve()) for p in args.files]
    for i, m in enumerate(mutants(sources, args.count, args.seed)):
        path = folder / f"{i:05d}.toml"
        path.write_bytes(m.data)
        cases.append((m.label, path))

    from concurrent.futures import ThreadPoolExecutor

    t0 = time.monotonic()
    results: list[dict[str, Any]] = []
    with ThreadPoolExecutor(max(1, args.jobs)) as pool:
        futures = [pool.submit(run_case, path, args.timeout, args.planner) for _, path in cases]
        for k, ((label, path), fut) in enumerate(zip(cases, futures, strict=True)):
            case = {"case": label, "file": str(path), **fut.result()}
            case["hang_in"] = ("load" if loads_in_process(path) != "loads" else "planning") if case["hang"] else ""
            case["bad"] = bad(case)
            results.append(case)
            if case["bad"]:
                print(f"  {path.name} {label}: {', '.join(case['bad'])}: {case['message'][:120]!r}", flush=True)
            if (k + 1) % 50 == 0:
                print(f"  ... {k + 1}/{len(cases)} in {time.monotonic() - t0:.0f} s", flush=True)

    codes = collections.Counter("hang" if c["hang"] else str(c["rc"]) for c in results)
    summary = {
        "cases": len(results),
        "seed": args.seed,
        "exit_codes": dict(sorted(codes.items())),
        "tracebacks": sum(c["traceback"] for c in results),
        "hangs_load": sum(c["hang_in"] == "load" for c in results),
        "hangs_planning": sum(c["hang_in"] == "planning" for c in results),
        "other_exit_codes": sum(not c["hang"] and c["rc"] not in (0, 1, 2) for c in results),
        "messages_over_limit": sum(c["message_len"] >= MESSAGE_LIMIT for c in results),
        "max_message_len": max((c["message_len"] for c in results), default=0),
        "max_rss_mb": max((c["max_rss_mb"] for c in results), default=0.0),
        "max_wall_s": max((c["wall_s"] for c in results), default=0.0),
        "max_cpu_s": max((c["cpu_s"] for c in results), default=0.0),
        "max_wall_s_exit2": max((c["wall_s"] for c in results if c["rc"] == 2), default=0.0),
        "bad_cases": sum(bool(c["bad"]) for c in results),
        "total_wall_s": round(time.monotonic() - t0, 1),
        "timeout_s": args.timeout,
        "mutants_in": str(folder),
    }
    for k, v in summary.items():
        print(f"{k:20s} {v}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"summary": summary, "cases": results}, indent=1) + "\n")
    return 0 if summary["bad_cases"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
