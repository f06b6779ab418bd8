"""A ground (propositional) PDDL copy of a :class:`GroundProblem`, for Fast Downward.

Used for problems that exist only in ground form, e.g. the GNPP reformulation (whose extra
conditional effects refer to specific ground atoms). Objects become domain constants, each
operator one parameter-less action named ``a<index>-<name>-<args>`` (the index maps FD's plan back
to our ground actions, whatever FD does to the case of names).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

from rlgp_exec.planning.symbolic.model import Atom, CondEffect, GroundAction, GroundProblem, Operator, atom_str

__all__ = ["GroundPDDL", "ground_to_pddl"]


@dataclass(frozen=True)
class GroundPDDL:
    domain: str
    problem: str
    actions: dict[str, GroundAction]  # FD action name (lower case) -> ours
    conditional_effects: bool


def _conj(pos: Iterable[Atom], neg: Iterable[Atom] = ()) -> str:
    parts = [atom_str(a) for a in sorted(pos)] + [f"(not {atom_str(a)})" for a in sorted(neg)]
    return f"(and {' '.join(parts)})"


def _effect(op: Operator) -> str:
    parts = [atom_str(a) for a in sorted(op.add)] + [f"(not {atom_str(a)})" for a in sorted(op.delete)]
    for ce in op.cond_effects:
        parts.append(f"(when {_conj(ce.cond, ce.cond_neg)} {_effect_conj(ce)})")
    return f"(and {' '.join(parts)})"


def _effect_conj(ce: CondEffect) -> str:
    return _conj(ce.add, ce.delete)


def _action_name(i: int, action: GroundAction) -> str:
    return "-".join((f"a{i}", action.name, *action.args)).lower()


def ground_to_pddl(problem: GroundProblem) -> GroundPDDL:
    """Domain and problem text of ``problem`` (STRIPS + negative preconditions + conditional effects)."""
    atoms: set[Atom] = set(problem.init) | set(problem.goal) | set(problem.goal_neg)
    for op in problem.operators:
        atoms |= op.pre | op.pre_neg | op.add | op.delete
        for ce in op.cond_effects:
            atoms |= ce.cond | ce.cond_neg | ce.add | ce.delete
    arity: dict[str, int] = {}
    for a in atoms:
        arity.setdefault(a[0], len(a) - 1)
    used = {x for a in atoms for x in a[1:]}
    constants = sorted(n for n, _ in problem.objects if n in used)
    cond = any(op.cond_effects for op in problem.operators)
    reqs = [":strips", ":negative-preconditions"] + ([":conditional-effects"] if cond else [])
    preds = [f"({p}{''.join(f' ?x{i}' for i in range(n))})" for p, n in sorted(arity.items())]
    names: dict[str, GroundAction] = {}
    lines = [
        f"(define (domain {problem.domain_name}-ground)",
        f"  (:requirements {' '.join(reqs)})",
        f"  (:constants {' '.join(constants)})" if constants else "",
        f"  (:predicates {' '.join(preds)})",
    ]
    for i, op in enumerate(problem.operators):
        name = _action_name(i, op.action)
        names[name] = op.action
        lines += [
            f"  (:action {name}",
            "    :parameters ()",
            f"    :precondition {_conj(op.pre, op.pre_neg)}",
            f"    :effect {_effect(op)})",
        ]
    lines.append(")")
    domain = "\n".join(ln for ln in lines if ln) + "\n"
    init = "\n    ".join(atom_str(a) for a in sorted(problem.init))
    text = (
        f"(define (problem {problem.name})\n  (:domain {problem.domain_name}-ground)\n"
        f"  (:init\n    {init})\n  (:goal {_conj(problem.goal, problem.goal_neg)}))\n"
    )
    return GroundPDDL(domain, text, names, cond)
