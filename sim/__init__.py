"""Simulation: PyBullet worlds built from scene files, rendered cameras, the simulated robot server."""
