"""rlgp-exec: a sense-plan-act executive for mobile manipulators (Toyota HSR, PR2)."""

from rlgp_exec.errors import ModelError, RlgpError, SceneError

__all__ = ["ModelError", "RlgpError", "SceneError", "__version__"]
__version__ = "0.1.0"
