"""Scenes: obstacles and a target, their exact signed distance, and anchor grids. Names are imported on first
use: the scene model and the generators' configs need no torch."""

from samp import lazy_exports

__getattr__, __all__ = lazy_exports(__name__, {
    **{name: "samp.scene.grid" for name in ("anchor_points", "grid_coords", "sample_grid")},
    **{name: "samp.scene.model" for name in ("DEFAULT_BOUNDS", "Box", "Cylinder", "MeshObstacle", "Pose", "Scene",
                                              "Sphere")},
    **{name: "samp.scene.registry" for name in ("available_generators", "generate_scene")}})
