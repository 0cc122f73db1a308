"""Scenes: obstacles and a target, their exact signed distance, and anchor grids."""

from samp.scene.grid import anchor_points, grid_coords, sample_grid
from samp.scene.model import DEFAULT_BOUNDS, Box, Cylinder, MeshObstacle, Pose, Scene, Sphere
from samp.scene.registry import available_generators, generate_scene

__all__ = ["DEFAULT_BOUNDS", "Box", "Cylinder", "MeshObstacle", "Pose", "Scene", "Sphere", "anchor_points",
           "available_generators", "generate_scene", "grid_coords", "sample_grid"]
