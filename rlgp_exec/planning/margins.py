"""The margins and tolerances both planners share, one value per notion (each module imports it from here)."""

from __future__ import annotations

__all__ = [
    "BASE_MARGIN", "FEAS_TOL", "PLACE_LIFT", "RELEASE_CLEARANCE", "REPLAY_CONTACT", "SELF_MARGIN", "TOOL_POS_TOL",
]

#: [m] the replay (``validate``) counts penetrations up to this deep as contacts, not collisions
REPLAY_CONTACT = 2e-3
#: [m or rad] an NLP's row counts as satisfied when it is off its bounds by no more (keyframes, paths, GNPP's
#: graph-NLPs and IK guesses, the reachability IK): well inside the replay's contact tolerance
FEAS_TOL = 1e-4
#: [m] an IK answer puts the tool within this of its target (the reachability graph's nodes, GNPP's guesses)
TOOL_POS_TOL = 2e-3
#: [m] a mobile base's footprint keeps this far from the fixtures' footprints (keyframes, paths, GNPP, as the
#: reachability graph's IK does): room for the base controller's tracking error
BASE_MARGIN = 0.02
#: [m] an object is released this far above its support, so the placed pose is not in contact at release
PLACE_LIFT = 0.003
#: [m] an object let go keeps this from each open finger: the replay's contact tolerance and a margin
RELEASE_CLEARANCE = 0.003
#: [m] the arm's spheres keep this from the robot's own body boxes (keyframes, level 3, GNPP)
SELF_MARGIN = 0.01
