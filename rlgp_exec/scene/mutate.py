"""Scene-file mutants for fuzzing the loader and the CLI: structural and value mutations of valid scene
files (deleted keys, swapped types, extreme numbers, NaN/inf, huge strings, deep nesting, copied tables)
and byte-level ones (truncation, flipped bytes, deleted lines), reproducible from a seed.

``mutants(sources, count, seed)`` yields ``Mutant(label, data)``: ``data`` is the file's bytes, written
with ``dump_toml`` from the mutated tables or cut from the original text.
"""

from __future__ import annotations

import contextlib
import copy
import json
import math
import random
import re
import tomllib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

__all__ = ["OPERATORS", "Mutant", "dump_toml", "mutants"]

_BARE_KEY = re.compile(r"[A-Za-z0-9_-]+")
_EXTREMES: tuple[float | int, ...] = (
    1e308, -1e308, 1e-300, -1e-300, 0.0, -0.0, 1e30, -1e30, 1e6, -1e6, 1e-6, 100.0, -100.0,
    10**30, -(10**30), 10**400, 2**63 - 1, 0, -1,
)
_TYPE_POOL: tuple[Any, ...] = ("x", "", 7, 1.5, True, [], {}, [1, 2], {"a": 1}, ["a", "b"], [[0.1]])
_HUGE = (10_000, 200_000, 2_000_000, 10_000_000)  # characters of a huge string
_DEEP = (12, 100, 1_000, 5_000)  # levels of a nested array


@dataclass(frozen=True)
class Mutant:
    label: str  # "<scene>:<operator>+..." for the report
    data: bytes


class _Raw:
    """A value ``dump_toml`` writes verbatim (nesting too deep to build as Python lists)."""

    def __init__(self, text: str) -> None:
        self.text = text


# ------------------------------------------------------------------------------------ writing TOML
def _key(k: str) -> str:
    return k if _BARE_KEY.fullmatch(k) else json.dumps(k, ensure_ascii=False)


def _value(v: Any) -> str:
    if isinstance(v, _Raw):
        return v.text
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)
    if isinstance(v, list):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{_key(k)} = {_value(x)}" for k, x in v.items()) + "}"
    raise TypeError(f"no TOML for {type(v).__name__}")


def dump_toml(data: dict[str, Any]) -> str:
    """``data`` as TOML: top-level tables as ``[name]``, arrays of tables as ``[[name]]``, the rest inline."""
    head, tail = [], []
    for k, v in data.items():
        if isinstance(v, dict):
            tail.append(f"\n[{_key(k)}]")
            tail += [f"{_key(k2)} = {_value(v2)}" for k2, v2 in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                tail.append(f"\n[[{_key(k)}]]")
                tail += [f"{_key(k2)} = {_value(v2)}" for k2, v2 in item.items()]
        else:
            head.append(f"{_key(k)} = {_value(v)}")
    return "\n".join(head + tail) + "\n"


# ------------------------------------------------------------------------------------ operators
Path_ = tuple[str | int, ...]


def _paths(data: Any) -> list[tuple[Path_, Any]]:
    """(path, value) of every table entry and array item below the top level."""
    out: list[tuple[Path_, Any]] = []
    stack: list[tuple[Path_, Any]] = [((), data)]
    while stack:
        path, v = stack.pop()
        items = v.items() if isinstance(v, dict) else enumerate(v) if isinstance(v, list) else ()
        for k, x in items:
            out.append(((*path, k), x))
            stack.append(((*path, k), x))
    return out


def _set(data: Any, path: Path_, value: Any) -> None:
    node = data
    for k in path[:-1]:
        node = node[k]
    node[path[-1]] = value


def _pick(rng: random.Random, data: Any, want: Any = None) -> Path_ | None:
    cands = [p for p, v in _paths(data) if want is None or want(v)]
    return rng.choice(cands) if cands else None


def _is_number(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _delete(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data)
    if path is None:
        return
    node: Any = data
    for k in path[:-1]:
        node = node[k]
    del node[path[-1]]


def _drop_table(rng: random.Random, data: dict[str, Any]) -> None:
    data.pop(rng.choice(sorted(data)), None)


def _type_swap(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data)
    if path is not None:
        _set(data, path, json.loads(json.dumps(rng.choice(_TYPE_POOL))))


def _extreme(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data, _is_number)
    if path is not None:
        _set(data, path, rng.choice(_EXTREMES))


def _nan_inf(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data, _is_number)
    if path is not None:
        _set(data, path, rng.choice((math.nan, math.inf, -math.inf)))


def _scale(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data, _is_number)
    if path is not None:
        node: Any = data
        for k in path[:-1]:
            node = node[k]
        # an integer beyond float range (from an earlier operator) is left as it is
        with contextlib.suppress(OverflowError):
            node[path[-1]] = node[path[-1]] * rng.choice((1e-3, 0.5, 1.05, 2.0, 1e3, -1.0))


def _huge_string(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data)
    if path is not None:
        _set(data, path, rng.choice("Ax(é ") * rng.choice(_HUGE))


def _deep(rng: random.Random, data: dict[str, Any]) -> None:
    path = _pick(rng, data)
    if path is not None:
        d = rng.choice(_DEEP)
        nested = "[" * d + "1" + "]" * d if rng.random() < 0.7 else "{a = " * d + "1" + "}" * d
        _set(data, path, _Raw(nested))


def _copies(rng: random.Random, data: dict[str, Any]) -> None:
    arrays = [k for k, v in data.items() if isinstance(v, list) and v]
    if arrays:
        arr = data[rng.choice(arrays)]
        item = rng.choice(arr)
        arr += [copy.deepcopy(item) for _ in range(rng.choice((1, 2, 70)))]


def _swap(rng: random.Random, data: dict[str, Any]) -> None:
    a, b = _pick(rng, data), _pick(rng, data)
    if a is None or b is None or a[: len(b)] == b or b[: len(a)] == a:
        return  # one inside the other: no swap
    va, vb = _get(data, a), _get(data, b)
    _set(data, a, vb)
    _set(data, b, va)


def _get(data: Any, path: Path_) -> Any:
    for k in path:
        data = data[k]
    return data


TableOp = Any  # Callable[[random.Random, dict[str, Any]], None]
_TABLE_OPS: dict[str, TableOp] = {
    "delete": _delete, "drop_table": _drop_table, "type_swap": _type_swap, "extreme": _extreme,
    "nan_inf": _nan_inf, "scale": _scale, "huge_string": _huge_string, "deep": _deep, "copies": _copies,
    "swap": _swap,
}


def _truncate(rng: random.Random, raw: bytes) -> bytes:
    return raw[: rng.randrange(len(raw))]


def _flip(rng: random.Random, raw: bytes) -> bytes:
    b = bytearray(raw)
    for _ in range(rng.choice((1, 2, 8))):
        b[rng.randrange(len(b))] = rng.choice((0x00, 0x80, 0xFF, 0xC3, 0x5B, 0x22, 0x3D, rng.randrange(256)))
    return bytes(b)


def _drop_line(rng: random.Random, raw: bytes) -> bytes:
    lines = raw.split(b"\n")
    del lines[rng.randrange(len(lines))]
    return b"\n".join(lines)


_BYTE_OPS = {"truncate": _truncate, "flip": _flip, "drop_line": _drop_line}
#: every operator's name, table-level then byte-level
OPERATORS: tuple[str, ...] = (*_TABLE_OPS, *_BYTE_OPS)


def mutants(sources: Sequence[tuple[str, bytes]], count: int, seed: int = 0) -> Iterator[Mutant]:
    """``count`` mutants of the scene files ``sources`` ((name, bytes) each), one to three operators each."""
    rng = random.Random(seed)
    parsed = [(name, raw, tomllib.loads(raw.decode())) for name, raw in sources]
    for _ in range(count):
        name, raw, data = rng.choice(parsed)
        ops = [rng.choice(OPERATORS) for _ in range(rng.choice((1, 1, 1, 2, 3)))]
        table_ops = [o for o in ops if o in _TABLE_OPS]
        out = raw
        if table_ops:
            d = copy.deepcopy(data)
            for o in table_ops:
                _TABLE_OPS[o](rng, d)
            out = dump_toml(d).encode()
        for o in ops:
            if o in _BYTE_OPS and out:
                out = _BYTE_OPS[o](rng, out)
        yield Mutant(f"{name}:{'+'.join(ops)}", out)
