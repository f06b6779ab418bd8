"""Options every IPOPT nlpsol of the package adds to its own (``LEAN``).

No ``nlp_grad`` function. nlpsol otherwise builds, by automatic differentiation at construction, the
Lagrangian's gradient in x and p, used only to report the multipliers ``lam_x`` / ``lam_p``, which no caller
reads (the solvers' x, f and g come from IPOPT itself). GNPP's graph-NLPs (tools/16's tower_pr2 corpus, 80
runs) built in 1.9 ms instead of 4.8 ms, their x, f, g and iteration counts bit-identical.

No MC64 permuting and scaling in MUMPS (``mumps_permuting_scaling`` 0; IPOPT's default, 7, lets MUMPS
choose, and it ran MC64 before every factorisation; IPOPT scales the NLP itself). Level 3's first segment of
pick_place_pr2 seed 1 (110 variables, 1360 rows): 143 -> 99 ms, the same 20 iterations and optimum.
Recorded GNPP corpora (tools/16, seed 0): every verdict and iteration count the same, CPU x0.89-0.94
(tower, Hanoi, obstacles). Side by side (stop 30, median planning time): pick_place_pr2 10 seeds 1.58 ->
1.46 s, sorting_pr2 10 seeds 1.60 -> 1.43 s, table_clearing_hsr 5 seeds 3.13 -> 2.33 s, every run solved,
the same base paths; GNPP 5 seeds, CPU: tower 2.60 -> 2.46 s, obstacles 3.93 -> 3.64 s, Hanoi 3.95 ->
4.19 s (the one Hanoi problem took another path: 478 NLPs against 471).
"""

from __future__ import annotations

__all__ = ["LEAN"]

LEAN: dict[str, bool | int] = {"no_nlp_grad": True, "calc_lam_p": False, "ipopt.mumps_permuting_scaling": 0}
