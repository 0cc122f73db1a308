"""What a depth camera produces, as reconstruction takes it: one sensor's observation (`Scan`) and the
depth image it came from (`DepthView`).

A `Scan` holds the sensor position and, in the robot base frame, the surface points it measured (`hits`)
and the ends of rays that met no obstacle (`free_ends`: pixels with no return, up to the far plane, and
pixels on the robot itself, up to the robot). The space along every ray up to its end is seen free;
without an `origin` nothing is known to be free. Scans come from `samp.sim.camera` (rendered) or from a
user's cloud files (`samp.perception.cloud.scan_from_file`); `samp.perception` reconstructs grids from them.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["DepthView", "Scan", "as_points"]


def as_points(array, what: str) -> np.ndarray:
    """Any (N, 3)-like array -> (N, 3) float64; ValueError naming `what` otherwise."""
    arr = np.asarray(array, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise ValueError(f"{what} must be an (N, 3) array of points in metres, got shape {arr.shape}")
    return arr


@dataclass
class DepthView:
    """The depth image a scan came from, for projective free-space carving (no gaps between rays).

    Args:
        depth: (H, W) metres along the optical axis per pixel: the measured surface, the robot's surface
            (free up to it), or the far plane (no return: free up to it); NaN: no information.
        intrinsics: (fx, fy, cx, cy) pixels, OpenCV convention; pose: (4, 4) camera -> base, optical axes.
    """

    depth: np.ndarray
    intrinsics: tuple[float, float, float, float]
    pose: np.ndarray


@dataclass
class Scan:
    """One sensor's observation in the robot base frame (metres).

    Args:
        hits: (N, 3) measured obstacle surface points.
        origin: (3,) sensor position, or None when unknown (then no free space is observed).
        free_ends: (K, 3) ends of rays seen free all the way (no return, or the robot's own surface).
        name: the sensor's name, for records and drawings.
        view: the depth image, when the scan is one (then free space is carved from it, not from rays).
    """

    hits: np.ndarray
    origin: np.ndarray | None = None
    free_ends: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))
    name: str = "cloud"
    view: DepthView | None = field(default=None, repr=False)

    def __post_init__(self):
        self.hits = as_points(self.hits, f"scan {self.name!r}: hits")
        self.free_ends = as_points(self.free_ends, f"scan {self.name!r}: free_ends")
        if self.origin is not None:
            self.origin = np.asarray(self.origin, dtype=np.float64).reshape(-1)
            if self.origin.shape != (3,) or not np.all(np.isfinite(self.origin)):
                raise ValueError(f"scan {self.name!r}: origin must be a finite (3,) sensor position, got {self.origin}")
        elif len(self.free_ends):
            raise ValueError(f"scan {self.name!r}: free_ends need the sensor origin they start from")
        if not (np.all(np.isfinite(self.hits)) and np.all(np.isfinite(self.free_ends))):
            raise ValueError(f"scan {self.name!r}: points must be finite; drop NaN or inf points first")
