"""``rlgp-exec bench``: each layer measured against its targets (planners, scaling, timing, perception,
the camera over the wire, the HAL, the reachability graph, the executive)."""
