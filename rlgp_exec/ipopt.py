"""Options every IPOPT nlpsol of the package adds to its own.

``LEAN``: no ``nlp_grad`` function. nlpsol otherwise builds, by automatic differentiation at construction,
the Lagrangian's gradient in x and p, used only to report the multipliers ``lam_x`` / ``lam_p``, which no
caller reads (the solvers' x, f and g come from IPOPT itself). GNPP's graph-NLPs (tools/16's tower_pr2
corpus, 80 runs) built in 1.9 ms instead of 4.8 ms, their x, f, g and iteration counts bit-identical.
"""

from __future__ import annotations

__all__ = ["LEAN"]

LEAN: dict[str, bool] = {"no_nlp_grad": True, "calc_lam_p": False}
