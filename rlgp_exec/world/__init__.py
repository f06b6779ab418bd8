"""The PyBullet world built from a scene file: the collision world the planners check and replay in,
its AprilTag quads, and its cameras' renderings."""

from rlgp_exec.world.pybullet_world import CabinetBody, World, build_world, matrix_to_pose

__all__ = ["CabinetBody", "World", "build_world", "matrix_to_pose"]
