"""A symbolic problem from a ``Scene``: typed objects, the initial state and the goal.

Typing (see ``domains/mobile_manipulation.pddl``): the robot's manipulators (PR2: right_arm,
left_arm; HSR: arm) are ``manipulator``; static fixtures are ``surface`` (their top holds any number
of objects); drawer cabinets are ``cabinet`` (a surface with a drawer, closed at the start unless ``scene.start``
has it out); a
region is a ``slot`` if it has room for a single object (the footprint of the largest movable
object fits at most once, e.g. a Hanoi peg) and a ``surface`` otherwise; movable objects are
``movable``. An object resting on a fixture whose centre lies inside a region of that fixture is
``on`` the region; one resting in ``<cabinet>.drawer`` is ``in`` the cabinet; the one in the hand (``scene.start.held``)
is held by it.
"""

from __future__ import annotations

import logging
import math
import re
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from rlgp_exec.planning.symbolic.errors import SymbolicError
from rlgp_exec.planning.symbolic.model import Atom, atom_str
from rlgp_exec.robot.config import load_robot_config
from rlgp_exec.scene.geometry import region_box
from rlgp_exec.scene.literals import parse_literal
from rlgp_exec.scene.types import Literal, Scene, SceneObject

__all__ = ["GOAL_KINDS", "ProblemSpec", "footprint", "problem_from_scene", "problem_to_pddl"]

log = logging.getLogger(__name__)

_NAME = re.compile(r"^[A-Za-z][A-Za-z0-9_-]*$")
_EPS = 1e-6

#: goal predicate -> the symbolic types each argument may have
GOAL_KINDS: dict[str, tuple[tuple[str, ...], ...]] = {
    "on": (("movable",), ("surface", "slot", "movable", "cabinet")),
    "in": (("movable",), ("cabinet",)),
    "open": (("cabinet",),),
    "closed": (("cabinet",),),
}


@dataclass(frozen=True)
class ProblemSpec:
    """The lifted problem: typed objects, initial atoms (static ones included) and goal atoms."""

    name: str
    domain_name: str
    objects: tuple[tuple[str, str], ...]  # (name, type)
    init: frozenset[Atom]
    goal: frozenset[Atom]

    def names_of(self, *types: str) -> list[str]:
        return [n for n, t in self.objects if t in types]


def footprint(obj: SceneObject) -> tuple[float, float]:
    """The object's footprint extents, sorted (small, large) [m]."""
    a, b = sorted(obj.size[:2])
    return (a, b)


def _fits(inner: tuple[float, float], outer: tuple[float, float]) -> bool:
    return inner[0] <= outer[0] + _EPS and inner[1] <= outer[1] + _EPS


def _check_name(name: str, what: str) -> None:
    if not _NAME.match(name):
        raise SymbolicError(f"{what} name {name!r} is not a PDDL name (letters, digits, '_' or '-', letter first)")


def _manipulators(scene: Scene, manipulators: Sequence[str] | None) -> list[str]:
    if manipulators is not None:
        return list(manipulators)

    return [m.name for m in load_robot_config(scene.robot.name).manipulators]


def _region_of(scene: Scene, obj: SceneObject, fixture: str) -> str | None:
    for r in scene.regions:
        if r.on != fixture:
            continue
        T = region_box(scene, r).T
        local = np.linalg.solve(T, np.array([obj.pose[0], obj.pose[1], T[2, 3], 1.0]))
        if abs(local[0]) <= r.size[0] / 2 + _EPS and abs(local[1]) <= r.size[1] / 2 + _EPS:
            return r.name
    return None


def _goal_atoms(literals: Sequence[str | Literal], types: dict[str, str]) -> frozenset[Atom]:
    by_type: dict[str, list[str]] = {}
    for n, t in types.items():
        by_type.setdefault(t, []).append(n)
    out: set[Atom] = set()
    for lit in literals:
        text = str(lit)
        if isinstance(lit, str):
            try:
                lit = parse_literal(lit)
            except ValueError as e:
                raise SymbolicError(f"goal literal {text!r}: {e}") from None
        if lit.predicate not in GOAL_KINDS:
            raise SymbolicError(f"goal literal {text!r}: unknown predicate; valid: {sorted(GOAL_KINDS)}")
        kinds = GOAL_KINDS[lit.predicate]
        if len(lit.args) != len(kinds):
            raise SymbolicError(f"goal literal {text!r}: takes {len(kinds)} argument(s), got {len(lit.args)}")
        for arg, allowed in zip(lit.args, kinds, strict=True):
            valid = sorted(n for t in allowed for n in by_type.get(t, []))
            if arg not in types:
                raise SymbolicError(f"goal literal {text!r} names unknown {'/'.join(allowed)} {arg!r}; valid: {valid}")
            if types[arg] not in allowed:
                raise SymbolicError(
                    f"goal literal {text!r}: {arg!r} is a {types[arg]}, expected {' or '.join(allowed)}; valid: {valid}"
                )
        if lit.predicate == "on" and lit.args[0] == lit.args[1]:
            raise SymbolicError(f"goal literal {text!r}: an object cannot be on itself")
        out.add((lit.predicate, *lit.args))
    return frozenset(out)


def problem_from_scene(
    scene: Scene,
    goal: Sequence[str | Literal] | None = None,
    manipulators: Sequence[str] | None = None,
    domain_name: str = "mobile_manipulation",
) -> ProblemSpec:
    """The symbolic problem of ``scene``; ``goal`` (literal strings) overrides ``scene.goal``.

    Raises SymbolicError for a goal literal naming an unknown or wrongly typed name (the message
    lists the valid names), or for scene names that are not PDDL names.
    """
    types: dict[str, str] = {}

    def declare(name: str, type_: str, what: str) -> None:
        _check_name(name, what)
        clash = [n for n in types if n.lower() == name.lower()]
        if clash:
            raise SymbolicError(f"{what} {name!r} clashes with {clash[0]!r} (PDDL names are case-insensitive)")
        types[name] = type_

    hands = _manipulators(scene, manipulators)
    if not hands:
        raise SymbolicError(f"scene {scene.name}: robot {scene.robot.name!r} has no manipulators")
    for m in hands:
        declare(m, "manipulator", "manipulator")
    for fx in scene.fixtures:
        declare(fx.name, "cabinet" if fx.kind == "drawer_cabinet" else "surface", "fixture")
    biggest = max((footprint(o)[1] for o in scene.objects), default=math.inf)
    for r in scene.regions:
        capacity = math.floor(r.size[0] / biggest + _EPS) * math.floor(r.size[1] / biggest + _EPS)
        declare(r.name, "slot" if capacity < 2 else "surface", "region")
    for o in scene.objects:
        declare(o.name, "movable", "object")

    held, holder = scene.start.held, scene.start.arm or hands[0]
    if held is not None and holder not in hands:
        raise SymbolicError(f"scene {scene.name}: {holder} holds {held!r}, but this problem plans for {hands} only")
    init: set[Atom] = {("hand-empty", m) for m in hands if not (held is not None and m == holder)}
    covered: set[str] = set()
    for o in scene.objects:
        if o.name == held:
            init.add(("holding", holder, o.name))
            covered.add(o.name)  # a held object is not clear (pick took that away; place gives it back)
            continue
        sup = o.support
        if sup.endswith(".drawer"):
            init.add(("in", o.name, sup.removesuffix(".drawer")))
            covered.add(o.name)  # nothing is stacked on an object inside a drawer
            continue
        if sup not in types:
            raise SymbolicError(f"scene {scene.name}: object {o.name!r} rests on unknown {sup!r}")
        if types[sup] in ("surface", "cabinet"):
            sup = _region_of(scene, o, sup) or sup
        init.add(("on", o.name, sup))
        covered.add(sup)
    for n, t in types.items():
        if t in ("movable", "slot") and n not in covered:
            init.add(("clear", n))
    for c in (n for n, t in types.items() if t == "cabinet"):
        init |= {("open" if scene.start.opening(c) > 0.0 else "closed", c), ("knob-free", c)}
    slots = {r.name: r for r in scene.regions if types[r.name] == "slot"}
    for o in scene.objects:
        fo = footprint(o)
        for other in scene.objects:
            if other.name != o.name and _fits(fo, footprint(other)):
                init.add(("stackable", o.name, other.name))
        for s in slots.values():
            if _fits(fo, (min(s.size), max(s.size))):
                init.add(("stackable", o.name, s.name))

    goal_lits: Sequence[str | Literal] = scene.goal.literals if goal is None else goal
    goal_atoms = _goal_atoms(goal_lits, types)
    spec = ProblemSpec(scene.name, domain_name, tuple(types.items()), frozenset(init), goal_atoms)
    log.debug(
        "problem %s: %d objects, %d init atoms, goal %s",
        spec.name,
        len(types),
        len(init),
        [atom_str(a) for a in sorted(goal_atoms)],
    )
    return spec


def problem_to_pddl(spec: ProblemSpec) -> str:
    """The PDDL problem text for the lifted domain."""
    objs = "\n    ".join(f"{n} - {t}" for n, t in spec.objects)
    init = "\n    ".join(atom_str(a) for a in sorted(spec.init))
    goal = " ".join(atom_str(a) for a in sorted(spec.goal))
    return (
        f"(define (problem {spec.name})\n  (:domain {spec.domain_name})\n"
        f"  (:objects\n    {objs})\n  (:init\n    {init})\n  (:goal (and {goal})))\n"
    )
