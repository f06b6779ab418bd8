"""Grounding: lifted action schemas x typed objects -> STRIPS operators (the Python successor model).

Every typed parameter assignment is enumerated; assignments whose static preconditions (predicates
no action changes, e.g. ``stackable``) do not hold in the initial state are dropped, and so are
operators that are not relaxed-reachable from the initial state.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence

from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.model import Atom, GroundAction, GroundProblem, Operator
from rlgp_exec.planning.symbolic.pddl import ActionSchema, AtomSchema, Domain, load_domain
from rlgp_exec.planning.symbolic.problem import ProblemSpec, problem_from_scene
from rlgp_exec.scene.types import Literal, Scene

__all__ = ["ground", "ground_scene"]

log = logging.getLogger(__name__)


def _bind(atom: AtomSchema, binding: dict[str, str]) -> Atom:
    return (atom.predicate, *(binding.get(a, a) for a in atom.args))


def _ground_schema(
    schema: ActionSchema,
    domain: Domain,
    objects: Sequence[tuple[str, str]],
    static: frozenset[str],
    init: frozenset[Atom],
) -> list[Operator]:
    domains: list[list[str]] = []
    for _var, type_ in schema.parameters:
        allowed = domain.subtypes(type_)
        names = [n for n, t in objects if t in allowed]
        if not names:
            return []
        domains.append(names)
    variables = [v for v, _ in schema.parameters]
    static_pre = [a for a in schema.pre if a.predicate in static]
    static_neg = [a for a in schema.pre_neg if a.predicate in static]
    out: list[Operator] = []
    for values in itertools.product(*domains):
        b = dict(zip(variables, values, strict=True))
        if any(_bind(a, b) not in init for a in static_pre) or any(_bind(a, b) in init for a in static_neg):
            continue
        out.append(
            Operator(
                GroundAction(schema.name, tuple(values)),
                frozenset(_bind(a, b) for a in schema.pre if a.predicate not in static),
                frozenset(_bind(a, b) for a in schema.pre_neg if a.predicate not in static),
                frozenset(_bind(a, b) for a in schema.add),
                frozenset(_bind(a, b) for a in schema.delete),
            )
        )
    return out


def _relaxed_reachable(ops: list[Operator], init: frozenset[Atom]) -> list[Operator]:
    reached = set(init)
    todo = list(ops)
    keep: list[Operator] = []
    grew = True
    while grew:
        grew = False
        rest = []
        for op in todo:
            if op.pre <= reached:
                keep.append(op)
                if not op.add <= reached:
                    reached |= op.add
                    grew = True
            else:
                rest.append(op)
        todo = rest
    order = {id(op): i for i, op in enumerate(ops)}
    return sorted(keep, key=lambda op: order[id(op)])


def ground(spec: ProblemSpec, domain: Domain | None = None) -> GroundProblem:
    """Ground ``spec`` against ``domain`` (default: the shipped domain of ``spec.domain_name``)."""
    domain = domain or load_domain(spec.domain_name)
    known_types = {t for t, _ in domain.types} | {"object"}
    for n, t in spec.objects:
        if t not in known_types:
            raise SymbolicError(f"{spec.name}: object {n!r} has unknown type {t!r}; valid: {sorted(known_types)}")
    static = frozenset(p for p, _ in domain.predicates) - domain.fluents
    ops: list[Operator] = []
    for schema in domain.actions:
        ops += _ground_schema(schema, domain, spec.objects, static, spec.init)
    n_all = len(ops)
    ops = _relaxed_reachable(ops, spec.init)
    init = frozenset(a for a in spec.init if a[0] not in static)
    log.debug("grounded %s: %d operators (%d relaxed-reachable)", spec.name, n_all, len(ops))
    return GroundProblem(spec.name, domain.name, spec.objects, init, spec.goal, tuple(ops))


def ground_scene(
    scene: Scene,
    goal: Sequence[str | Literal] | None = None,
    manipulators: Sequence[str] | None = None,
) -> GroundProblem:
    """``ground(problem_from_scene(scene, goal, manipulators))``."""
    return ground(problem_from_scene(scene, goal=goal, manipulators=manipulators))
