"""``guess.ik_seed``: the start it gives a subgraph's solve reaches the solver (a value the presolve merges
away is no start)."""

from __future__ import annotations

import numpy as np

from rlgp_exec.planning.gnpp.geometry import FactorLib
from rlgp_exec.planning.gnpp.graph import variables
from rlgp_exec.planning.gnpp.guess import TopIK, ik_seed, initial_guess
from rlgp_exec.planning.gnpp.pntc import add_flags, add_moves, factors_of
from rlgp_exec.planning.gnpp.solver import GraphSolver
from rlgp_exec.planning.symbolic import GroundAction, ground_scene
from rlgp_exec.robot import load_robot
from rlgp_exec.scene.generate import sorting_scene


def test_a_seeded_place_starts_its_whole_held_chain_at_the_new_grasp():
    """A place carried by ``Equal`` from the pick: the held pose ``ik_seed`` computes goes to every pose of
    the chain (the solver starts the merged chain from its earliest), not only to the place's own."""
    scene = sorting_scene("hsr", 2, 0)
    lib = FactorLib(load_robot("hsr"), scene)
    ik, arm = TopIK(lib), lib.arms[0]
    block = next(o.name for o in scene.objects if o.name.startswith("block_blue"))
    task = add_flags(add_moves(ground_scene(scene, manipulators=[arm]), [arm], lib.riders))
    acts = ["(start-move arm)", "(end-move arm)", f"(pick arm {block} table_mid)", "(start-move arm)",
            "(end-move arm)", f"(place arm {block} tray_blue)"]
    states = task.simulate([GroundAction.parse(a) for a in acts])
    graph = factors_of(states, [arm], [o.name for o in scene.objects], [arm], lib.riders)
    guess = initial_guess(lib, ik, states, variables(graph))
    place = [f for f in graph if f.kind == "Kin" and f.key[1] == block][-1]
    r_var = place.vars[2]
    held, chain = {r_var}, []
    for f in sorted((f for f in graph if f.kind == "Equal"), key=lambda f: -f.vars[0].t):  # back from the place
        if f.vars[1] in held:
            held.add(f.vars[0])
            chain.append(f)
    sub = [place, *(f for f in graph if f.kind in ("Grasp", "Place") and f.vars[0].owner == block), *chain]
    assert len(held) >= 3, "the place's held pose is carried from the pick by Equal"
    stale = dict(guess)
    first = min(held)
    stale[first] = np.array([0.015, 0.0, np.pi / 2, 0.875])  # a quarter turn, tilted: where a solve can stall
    seeded = ik_seed(lib, ik, sub, stale)
    for v in held:
        assert np.allclose(seeded[v], seeded[r_var]), v
    assert not np.allclose(seeded[first], stale[first])
    assert GraphSolver(lib).solve(sub, seeded).feasible
