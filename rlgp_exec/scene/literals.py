"""Goal literals: ``(predicate arg ...)`` strings checked against the scene's names."""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence

from rlgp_exec.errors import SceneError
from rlgp_exec.scene.rules import quote
from rlgp_exec.scene.types import Literal, Scene

__all__ = ["PREDICATES", "parse_goal", "parse_literal"]

#: predicate -> the kinds each argument may name
PREDICATES: dict[str, tuple[tuple[str, ...], ...]] = {
    "on": (("object",), ("region", "fixture", "object")),
    "in": (("object",), ("cabinet",)),
    "open": (("cabinet",),),
    "closed": (("cabinet",),),
}
_LITERAL = re.compile(r"^\(\s*([A-Za-z_][\w-]*)((?:\s+[^\s()]+)*)\s*\)$")

Fail = Callable[[str, str], SceneError]


def parse_literal(text: str) -> Literal:
    """``"(on a b)"`` -> Literal("on", ("a", "b")); raises ValueError on bad syntax or predicate."""
    m = _LITERAL.match(text.strip())
    if not m:
        raise ValueError(f"{quote(text)} is not a literal like '(on block tray)'")
    pred, args = m.group(1), tuple(m.group(2).split())
    if pred not in PREDICATES:
        raise ValueError(f"unknown predicate {quote(pred)}; valid: {sorted(PREDICATES)}")
    if len(args) != len(PREDICATES[pred]):
        raise ValueError(f"({pred} ...) takes {len(PREDICATES[pred])} argument(s), got {len(args)}")
    return Literal(pred, args)


def _kinds(scene: Scene) -> dict[str, str]:
    kinds: dict[str, str] = {}
    for f in scene.fixtures:
        kinds[f.name] = "cabinet" if f.kind == "drawer_cabinet" else "fixture"
    kinds.update({o.name: "object" for o in scene.objects})
    kinds.update({r.name: "region" for r in scene.regions})
    return kinds


def parse_goal(literals: Sequence[str], scene: Scene, fail: Fail) -> tuple[Literal, ...]:
    """Parse and check every literal: predicate, arity, and that each argument names the right kind."""
    kinds = _kinds(scene)
    out: list[Literal] = []
    for i, text in enumerate(literals):
        where = f"[goal].literals[{i}]"
        try:
            lit = parse_literal(text)
        except ValueError as e:
            raise fail(where, str(e)) from None
        for arg, allowed in zip(lit.args, PREDICATES[lit.predicate], strict=True):
            kind = kinds.get(arg)
            if kind is None:
                raise fail(where, f"{quote(text)} names unknown {'/'.join(allowed)} {quote(arg)}")
            if kind not in allowed:
                raise fail(where, f"{quote(text)}: {arg!r} is a {kind}, expected a {' or '.join(allowed)}")
        if lit.predicate == "on" and lit.args[0] == lit.args[1]:
            raise fail(where, f"{quote(text)}: an object cannot be on itself")
        out.append(lit)
    return tuple(out)
