"""Options every IPOPT nlpsol of the package adds to its own (``LEAN``).

No ``nlp_grad`` function: nlpsol otherwise builds, by automatic differentiation at construction, the
Lagrangian's gradient in x and p, used only to report the multipliers ``lam_x`` / ``lam_p``, which no caller
reads (the solvers' x, f and g come from IPOPT itself).

No MC64 permuting and scaling in MUMPS (``mumps_permuting_scaling`` 0): IPOPT's default lets MUMPS run MC64
before every factorisation, while IPOPT scales the NLP itself. The measurements behind both are in
``docs/decisions/2026-11-solver-options.md``.
"""

from __future__ import annotations

__all__ = ["LEAN"]

LEAN: dict[str, bool | int] = {"no_nlp_grad": True, "calc_lam_p": False, "ipopt.mumps_permuting_scaling": 0}
