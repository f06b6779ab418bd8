"""Optimisation layers shared by the planners: constraint factors and the keyframe (mode-switch) NLP."""

from rlgp_exec.planning.nlp.action import Action
from rlgp_exec.planning.nlp.keyframes import KeyframeResult, solve_keyframes

__all__ = ["Action", "KeyframeResult", "solve_keyframes"]
