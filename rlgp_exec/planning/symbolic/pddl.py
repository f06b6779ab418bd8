"""The PDDL domain: a small parser and writer for the STRIPS + typing (+ negative preconditions) subset.

The shipped ``domains/*.pddl`` files are the single definition of the symbolic domain. They are
parsed into :class:`Domain` (typed action schemas), which the grounder turns into the Python
successor model, and written back with :func:`domain_to_pddl` for Fast Downward, so the text the
planner reads and the model our own search uses cannot drift apart.
"""

from __future__ import annotations

import logging
import re
from dataclasses import dataclass
from importlib import resources

from rlgp_exec.planning.symbolic.errors import SymbolicError

__all__ = [
    "DOMAINS",
    "ActionSchema",
    "AtomSchema",
    "Domain",
    "SExpr",
    "domain_to_pddl",
    "load_domain",
    "parse_domain",
    "parse_sexpr",
]

log = logging.getLogger(__name__)

#: The domains shipped as package data (``rlgp_exec/planning/symbolic/domains/<name>.pddl``).
DOMAINS: tuple[str, ...] = ("mobile_manipulation",)

SExpr = str | list["SExpr"]
_TOKEN = re.compile(r"\(|\)|[^\s()]+")


def parse_sexpr(text: str) -> SExpr:
    """Parse one s-expression (``;`` comments removed, names lower-cased as PDDL is case-insensitive)."""
    text = "\n".join(line.split(";", 1)[0] for line in text.splitlines())
    stack: list[list[SExpr]] = [[]]
    for tok in _TOKEN.findall(text):
        if tok == "(":
            stack.append([])
        elif tok == ")":
            if len(stack) == 1:
                raise SymbolicError("PDDL: unbalanced ')'")
            done = stack.pop()
            stack[-1].append(done)
        else:
            stack[-1].append(tok.lower())
    if len(stack) != 1:
        raise SymbolicError(f"PDDL: {len(stack) - 1} unclosed '('")
    if len(stack[0]) != 1:
        raise SymbolicError(f"PDDL: expected one top-level expression, got {len(stack[0])}")
    return stack[0][0]


@dataclass(frozen=True)
class AtomSchema:
    """``(predicate ?var-or-constant ...)``."""

    predicate: str
    args: tuple[str, ...]

    def __str__(self) -> str:
        return f"({' '.join((self.predicate, *self.args))})"


@dataclass(frozen=True)
class ActionSchema:
    name: str
    parameters: tuple[tuple[str, str], ...]  # (?var, type)
    pre: tuple[AtomSchema, ...]
    pre_neg: tuple[AtomSchema, ...]
    add: tuple[AtomSchema, ...]
    delete: tuple[AtomSchema, ...]


@dataclass(frozen=True)
class Domain:
    name: str
    requirements: tuple[str, ...]
    types: tuple[tuple[str, str], ...]  # (type, parent), in file order
    predicates: tuple[tuple[str, tuple[tuple[str, str], ...]], ...]  # (name, ((?var, type), ...))
    actions: tuple[ActionSchema, ...]

    def action(self, name: str) -> ActionSchema:
        for a in self.actions:
            if a.name == name:
                return a
        raise SymbolicError(f"domain {self.name}: unknown action {name!r}; valid: {[a.name for a in self.actions]}")

    def subtypes(self, type_: str) -> frozenset[str]:
        """``type_`` and every type below it."""
        out = {type_}
        grew = True
        while grew:
            grew = False
            for t, parent in self.types:
                if parent in out and t not in out:
                    out.add(t)
                    grew = True
        return frozenset(out)

    @property
    def fluents(self) -> frozenset[str]:
        """Predicates some action changes (the rest are static)."""
        return frozenset(a.predicate for s in self.actions for a in (*s.add, *s.delete))


def _typed_list(items: list[SExpr], where: str) -> tuple[tuple[str, str], ...]:
    out: list[tuple[str, str]] = []
    pending: list[str] = []
    i = 0
    while i < len(items):
        tok = items[i]
        if not isinstance(tok, str):
            raise SymbolicError(f"PDDL {where}: unexpected list {tok!r} in a typed list")
        if tok == "-":
            if i + 1 >= len(items) or not isinstance(items[i + 1], str):
                raise SymbolicError(f"PDDL {where}: '-' must be followed by a type name")
            out.extend((p, str(items[i + 1])) for p in pending)
            pending = []
            i += 2
            continue
        pending.append(tok)
        i += 1
    out.extend((p, "object") for p in pending)
    return tuple(out)


def _atom(e: SExpr, where: str) -> AtomSchema:
    if not isinstance(e, list) or not e or not all(isinstance(x, str) for x in e):
        raise SymbolicError(f"PDDL {where}: expected an atom like (on ?o ?s), got {e!r}")
    return AtomSchema(str(e[0]), tuple(str(x) for x in e[1:]))


def _conjunction(e: SExpr, where: str) -> tuple[list[AtomSchema], list[AtomSchema]]:
    """``(and a (not b) ...)`` or a single literal -> (positive, negative)."""
    if isinstance(e, list) and e and e[0] == "and":
        parts = e[1:]
    elif isinstance(e, list) and not e:
        parts = []
    else:
        parts = [e]
    pos: list[AtomSchema] = []
    neg: list[AtomSchema] = []
    for p in parts:
        if isinstance(p, list) and p and p[0] == "not":
            neg.append(_atom(p[1], where))
        elif isinstance(p, list) and p and p[0] in ("or", "when", "forall", "exists", "imply", "="):
            raise SymbolicError(
                f"PDDL {where}: {p[0]!r} is not supported; valid: atoms, (not atom) and (and ...) of them"
            )
        else:
            pos.append(_atom(p, where))
    return pos, neg


def _action(e: list[SExpr]) -> ActionSchema:
    name = str(e[1])
    where = f"action {name}"
    fields: dict[str, SExpr] = {}
    for i in range(2, len(e) - 1, 2):
        fields[str(e[i])] = e[i + 1]
    unknown = set(fields) - {":parameters", ":precondition", ":effect"}
    if unknown:
        raise SymbolicError(f"PDDL {where}: unknown fields {sorted(unknown)}; valid: :parameters :precondition :effect")
    params_raw = fields.get(":parameters", [])
    params = _typed_list(params_raw if isinstance(params_raw, list) else [params_raw], where)
    pre, pre_neg = _conjunction(fields.get(":precondition", []), where + " :precondition")
    add, delete = _conjunction(fields.get(":effect", []), where + " :effect")
    variables = {p for p, _ in params}
    for atom in (*pre, *pre_neg, *add, *delete):
        for arg in atom.args:
            if arg.startswith("?") and arg not in variables:
                raise SymbolicError(f"PDDL {where}: {atom} uses {arg}, not a parameter; valid: {sorted(variables)}")
    return ActionSchema(name, params, tuple(pre), tuple(pre_neg), tuple(add), tuple(delete))


def parse_domain(text: str) -> Domain:
    """Parse a domain file of the supported subset; anything else raises SymbolicError naming it."""
    e = parse_sexpr(text)
    if (
        not isinstance(e, list)
        or len(e) < 2
        or e[0] != "define"
        or not isinstance(e[1], list)
        or e[1][:1] != ["domain"]
    ):
        raise SymbolicError("PDDL: expected (define (domain NAME) ...)")
    name = str(e[1][1])
    requirements: tuple[str, ...] = ()
    types: tuple[tuple[str, str], ...] = ()
    predicates: list[tuple[str, tuple[tuple[str, str], ...]]] = []
    actions: list[ActionSchema] = []
    for section in e[2:]:
        if not isinstance(section, list) or not section:
            raise SymbolicError(f"PDDL domain {name}: unexpected {section!r}")
        head = section[0]
        if head == ":requirements":
            requirements = tuple(str(r) for r in section[1:])
        elif head == ":types":
            types = _typed_list(section[1:], f"domain {name} :types")
        elif head == ":predicates":
            for p in section[1:]:
                if not isinstance(p, list) or not p:
                    raise SymbolicError(f"PDDL domain {name}: bad predicate {p!r}")
                predicates.append((str(p[0]), _typed_list(p[1:], f"predicate {p[0]}")))
        elif head == ":action":
            actions.append(_action(section))
        else:
            raise SymbolicError(
                f"PDDL domain {name}: unsupported section {head!r}; valid: :requirements :types :predicates :action"
            )
    known = {p for p, _ in predicates}
    for a in actions:
        for atom in (*a.pre, *a.pre_neg, *a.add, *a.delete):
            if atom.predicate not in known:
                raise SymbolicError(
                    f"PDDL action {a.name}: unknown predicate {atom.predicate!r}; valid: {sorted(known)}"
                )
    return Domain(name, requirements, types, tuple(predicates), tuple(actions))


def load_domain(name: str = "mobile_manipulation") -> Domain:
    """A shipped domain by name (see :data:`DOMAINS`)."""
    if name not in DOMAINS:
        raise SymbolicError(f"unknown domain {name!r}; valid: {list(DOMAINS)}")
    text = resources.files("rlgp_exec.planning.symbolic").joinpath("domains", f"{name}.pddl").read_text()
    domain = parse_domain(text)
    log.debug("loaded domain %s: %d actions", domain.name, len(domain.actions))
    return domain


def _typed(items: tuple[tuple[str, str], ...]) -> str:
    return " ".join(f"{n} - {t}" for n, t in items)


def _conj(pos: tuple[AtomSchema, ...], neg: tuple[AtomSchema, ...]) -> str:
    parts = [str(a) for a in pos] + [f"(not {a})" for a in neg]
    return f"(and {' '.join(parts)})"


def domain_to_pddl(domain: Domain) -> str:
    """PDDL text of ``domain``; ``parse_domain(domain_to_pddl(d)) == d``."""
    reqs = set(domain.requirements)
    if any(a.pre_neg for a in domain.actions):
        reqs.add(":negative-preconditions")
    lines = [
        f"(define (domain {domain.name})",
        f"  (:requirements {' '.join(sorted(reqs))})",
        f"  (:types {_typed(domain.types)})",
        "  (:predicates",
        *(f"    ({p} {_typed(args)})" for p, args in domain.predicates),
        "  )",
    ]
    for a in domain.actions:
        lines += [
            f"  (:action {a.name}",
            f"    :parameters ({_typed(a.parameters)})",
            f"    :precondition {_conj(a.pre, a.pre_neg)}",
            f"    :effect {_conj(a.add, ())[:-1]}{''.join(f' (not {d})' for d in a.delete)})",
            "  )",
        ]
    lines.append(")")
    return "\n".join(lines) + "\n"
