"""Optimisation layers shared by the planners: constraint factors and the keyframe (mode-switch) NLP."""

from rlgp_exec.planning.nlp.keyframes import Action, KeyframeResult, solve_keyframes

__all__ = ["Action", "KeyframeResult", "solve_keyframes"]
