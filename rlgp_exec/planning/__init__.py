"""Task-and-motion planners (R-LGP, GNPP) and their shared layers; see ``symbolic`` for the logic side."""
