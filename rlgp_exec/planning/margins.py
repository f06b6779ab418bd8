"""The margins and tolerances both planners share, one value per notion (each module imports it from here)."""

from __future__ import annotations

__all__ = ["BASE_MARGIN", "FEAS_TOL", "PLACE_LIFT"]

#: [m or rad] an NLP's row counts as satisfied when it is off its bounds by no more (keyframes, paths, GNPP's
#: graph-NLPs): well inside the replay's 2 mm contact tolerance
FEAS_TOL = 1e-4
#: [m] a mobile base's footprint keeps this far from the fixtures' footprints (keyframes, paths, GNPP, as the
#: reachability graph's IK does): room for the base controller's tracking error
BASE_MARGIN = 0.02
#: [m] an object is released this far above its support, so the placed pose is not in contact at release
PLACE_LIFT = 0.003
