"""Perception: anchor grids reconstructed from point clouds (simulated depth cameras or a user's files).

    from samp.perception import reconstruct_grid, scan_from_file
    with World(robot, scene) as world:
        scans = world.capture("default")                       # conf/camera/default.yaml
    grid = reconstruct_grid(scans, 100, scene.bounds, unknown="occupied").grid   # (100, 100, 100)
    grid = reconstruct_grid([scan_from_file("cloud.ply", origin=[1.2, 0, 1.0])], 100, bounds).grid

Names are imported on first use.
"""

from importlib import import_module

_EXPORTS = {
    "DepthView": "cloud", "Scan": "cloud", "load_point_cloud": "cloud", "save_point_cloud": "cloud",
    "scan_from_file": "cloud",
    "FREE": "reconstruct", "OCCUPIED": "reconstruct", "UNKNOWN": "reconstruct", "UNKNOWN_POLICIES": "reconstruct",
    "Lattice": "reconstruct", "Reconstruction": "reconstruct", "observe": "reconstruct",
    "reconstruct_grid": "reconstruct", "reconstruction_error": "reconstruct", "signed_distance": "reconstruct",
    "ReconstructedGrids": "source", "SceneReconstruction": "source",
    "write_reconstruction_recording": "viz",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'samp.perception' has no attribute {name!r}")
    value = getattr(import_module(f"samp.perception.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value
