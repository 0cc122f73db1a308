"""The anchor grid from point clouds: an occupancy volume, then signed distances by Euclidean distance
transforms (`scipy.ndimage.distance_transform_edt`).

The volume is the anchor lattice itself (voxel centres at the anchors: n_e per axis, inclusive linspace
over the bounds, index order (x, y, z), docs/design.md section 4), extended by `padding` metres on every side so
that obstacles just outside the bounds (the table top lies 5 cm under the default bounds) still set the
distances inside. Every voxel is one of:

* occupied: a measured surface point falls in it;
* free: some ray passed through it before reaching its end (free-space carving);
* unknown: neither, e.g. the inside of obstacles, space hidden behind them, space no camera looks at.

Unknown voxels inside the bounds are then treated as `unknown="occupied"` (conservative: hidden space may hold an
obstacle, and obstacle interiors get negative distances as in the exact grid) or `unknown="free"`
(optimistic: only measured surfaces are obstacles, so interiors read as small positive distances).
In the padding only measured surfaces count, whatever the policy: space above or beside the workspace
that no camera sees would otherwise become a wall around it.
A `known_free` test (the robot's own volume at capture time) turns unknown voxels free first, so the
robot, whose points were removed from the clouds, does not become an obstacle under "occupied". The
space the robot hides from the cameras still does: on the generated scenes with conf/camera/default at
n_e = 100, "occupied" gave a MAE of 127-223 mm over all anchors (phantom obstacles around the robot)
against 2-4 mm with "free", so "free" is the default.

Accuracy: the distances are those between voxel centres, so expect errors up to about a voxel near
surfaces; under "occupied", space near surfaces that no camera carved reads as obstacle, which biases
distances low (conservative) by a few millimetres.

Signed distance, with O the occupied set after the policy and h the voxel spacing per axis:
outside O, the EDT distance to the nearest voxel of O; inside O, minus (the EDT distance to the nearest
voxel outside O, less one voxel). A surface voxel holds the surface somewhere within it, so it reads 0,
and the error is at most about half a voxel plus the voxelisation of the surface.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np
import torch
from scipy.ndimage import distance_transform_edt, minimum_filter

from samp.scene.model import check_bounds
from samp.sim.scan import DepthView, Scan

__all__ = ["FREE", "OCCUPIED", "UNKNOWN", "UNKNOWN_POLICIES", "Lattice", "Reconstruction", "checked_scans", "observe",
           "reconstruct_grid", "reconstruction_error", "signed_distance"]

UNKNOWN, FREE, OCCUPIED = 0, 1, 2  # voxel states (int8)
UNKNOWN_POLICIES = ("occupied", "free")
NEAR = 0.05  # metres: the reconstruction error is reported over anchors with |exact distance| below this
RAY_CHUNK = 4_000_000  # ray samples handled at once (bounds the memory of carving)
# Sanity of the clouds: below MIN_INSIDE points, or below MIN_INSIDE_SHARE of them, inside the padded
# workspace, the clouds cannot describe it (wrong units or frame): an error. Above WARN_OUTSIDE_SHARE outside,
# a warning (bounds tighter than the scene are legitimate; a shifted cloud is not). On the generated scenes
# seen by conf/camera/default all points lie inside; shifted 1 m along x, 29-42 % of them do.
MIN_INSIDE, MIN_INSIDE_SHARE, WARN_OUTSIDE_SHARE = 10, 0.01, 0.5
WARN_ON_ROBOT_SHARE = 0.05  # of the points inside, on the robot's own (known free) volume: another frame?
MILLIMETRES = 20.0  # metres: a cloud wider than this is most likely in millimetres


@dataclass(frozen=True)
class Lattice:
    """The padded voxel lattice: the anchors of (n_e, bounds) and `pad` (3,) extra voxels per side.

    Attributes:
        n_e: anchors per axis; pad: (3,) int voxels added on each side of each axis.
        spacing: (3,) metres between anchors; first: (3,) centre of voxel (0, 0, 0); shape: padded (3,).
    """

    n_e: int
    bounds: tuple
    pad: tuple[int, int, int]

    @staticmethod
    def make(n_e: int, bounds, padding: float) -> "Lattice":
        from samp.scene.grid import check_n_e

        n_e = check_n_e(n_e)
        if not (math.isfinite(padding) and padding >= 0):
            raise ValueError(f"padding must be a non-negative number of metres, got {padding!r}")
        lo, hi = np.asarray(check_bounds(bounds))
        h = (hi - lo) / (n_e - 1)
        return Lattice(int(n_e), check_bounds(bounds), tuple(int(p) for p in np.ceil(padding / h - 1e-9)))

    @property
    def spacing(self) -> np.ndarray:
        lo, hi = np.asarray(self.bounds)
        return (hi - lo) / (self.n_e - 1)

    @property
    def first(self) -> np.ndarray:
        return np.asarray(self.bounds[0]) - np.asarray(self.pad) * self.spacing

    @property
    def shape(self) -> tuple[int, int, int]:
        return tuple(self.n_e + 2 * p for p in self.pad)

    def index(self, points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, 3) points -> flat voxel indices (N,) int64 and (N,) bool: inside the padded lattice."""
        ijk = np.rint((points - self.first) / self.spacing).astype(np.int64)
        inside = np.all((ijk >= 0) & (ijk < self.shape), axis=-1)
        ijk = np.where(inside[..., None], ijk, 0)
        return np.ravel_multi_index(np.moveaxis(ijk, -1, 0), self.shape), inside

    def crop(self, volume: np.ndarray) -> np.ndarray:
        """Padded (X, Y, Z) volume -> (n_e, n_e, n_e) at the anchors."""
        (px, py, pz), n = self.pad, self.n_e
        return volume[px:px + n, py:py + n, pz:pz + n]

    def centres(self, flat: np.ndarray) -> np.ndarray:
        """(N,) flat voxel indices -> (N, 3) voxel centres."""
        return np.stack(np.unravel_index(flat, self.shape), axis=1) * self.spacing + self.first


def _box_entry_exit(origin: np.ndarray, dirs: np.ndarray, lo: np.ndarray, hi: np.ndarray):
    """Slab test: ray parameters (R,) where unit rays origin + t dirs (R, 3) enter and leave the box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        inv = 1.0 / dirs
        t_lo, t_hi = (lo - origin) * inv, (hi - origin) * inv  # (R, 3); inf or nan on axis-parallel rays
    t_lo = np.where(np.isnan(t_lo), -np.inf, t_lo)
    t_hi = np.where(np.isnan(t_hi), np.inf, t_hi)
    return np.maximum(np.minimum(t_lo, t_hi).max(axis=1), 0.0), np.maximum(t_lo, t_hi).min(axis=1)


def _carve(free: np.ndarray, lattice: Lattice, origin: np.ndarray, ends: np.ndarray, stop: float) -> None:
    """Mark free (flat bool, in place) every voxel that rays origin -> ends (R, 3) pass through, each ray
    stopping `stop` metres short of its end; rays are sampled every min(spacing) within the lattice."""
    step = float(lattice.spacing.min())
    vec = ends - origin
    length = np.linalg.norm(vec, axis=1)
    keep = length > stop
    dirs, length = vec[keep] / length[keep, None], length[keep] - stop
    box_lo = lattice.first - lattice.spacing / 2
    t0, t1 = _box_entry_exit(origin, dirs, box_lo, box_lo + np.asarray(lattice.shape) * lattice.spacing)
    t1 = np.minimum(t1, length)
    live = t1 > t0
    dirs, t0, t1 = dirs[live], t0[live], t1[live]
    samples = np.ceil((t1 - t0) / step).astype(np.int64) + 1  # (R,)
    order = np.argsort(samples)  # similar lengths together: little padding per chunk
    per_chunk = max(1, RAY_CHUNK // int(samples.max(initial=1)))
    for start in range(0, len(order), per_chunk):
        rows = order[start:start + per_chunk]
        k = int(samples[rows[-1]])
        t = t0[rows, None] + step * np.arange(k)  # (r, k)
        ok = t <= t1[rows, None]
        pts = origin + dirs[rows, None, :] * t[..., None]  # (r, k, 3)
        flat, inside = lattice.index(pts[ok])
        free[flat[inside]] = True


def _carve_view(free: np.ndarray, lattice: Lattice, view: DepthView) -> None:
    """Mark free (flat bool, in place) every voxel that lies wholly in front of the depth seen at the pixel
    its centre projects to (projective carving, as in TSDF fusion). "Wholly": the centre is in front by
    more than the voxel's half extent along the viewing ray."""
    fx, fy, cx, cy = view.intrinsics
    H, W = view.depth.shape
    # The nearest depth in each pixel's 3x3 neighbourhood: a voxel centre inside an obstacle but close to its
    # silhouette may project onto a pixel that sees past it, and must not be carved (dropped pixels ignored).
    depth = minimum_filter(np.where(np.isnan(view.depth), np.inf, view.depth), size=3, mode="nearest")
    depth[np.isnan(view.depth)] = np.nan
    R, t = view.pose[:3, :3], view.pose[:3, 3]
    half = lattice.spacing / 2
    chunk = max(1, RAY_CHUNK // 4)
    for start in range(0, free.size, chunk):
        flat = np.arange(start, min(start + chunk, free.size))
        offset = lattice.centres(flat) - t  # (N, 3) base frame, from the camera
        local = offset @ R  # (N, 3) camera frame
        z, dist = local[:, 2], np.linalg.norm(offset, axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            u, v = np.rint(fx * local[:, 0] / z + cx), np.rint(fy * local[:, 1] / z + cy)
            reach = (np.abs(offset) @ half) / dist * z / dist  # the voxel's half extent along the ray, as depth
        seen = (z > 0) & (u >= 0) & (u < W) & (v >= 0) & (v < H)
        d = depth[v[seen].astype(np.int64), u[seen].astype(np.int64)]  # NaN (dropped) compares False
        free[flat[seen][z[seen] + reach[seen] < d]] = True


def observe(scans: Sequence[Scan], lattice: Lattice, known_free: Callable[[np.ndarray], np.ndarray] | None = None
            ) -> np.ndarray:
    """Voxel states (X, Y, Z) int8 of the padded lattice: UNKNOWN, FREE or OCCUPIED.

    A scan with its depth image is carved projectively; one with only a sensor origin (a cloud file) along
    its rays, sampled every voxel (far from the sensor, rays may pass between voxels and leave them
    unknown). Free space ends one voxel short of a measured surface, whose voxel is occupied by its
    point; hits win over free. `known_free` maps (N, 3) voxel centres to
    (N,) bool and turns those unknown voxels free.
    """
    size = int(np.prod(lattice.shape))
    free, occupied = np.zeros(size, dtype=bool), np.zeros(size, dtype=bool)
    stop = 0.5 * float(lattice.spacing.max())  # a voxel whose centre is this far in front cannot hold the surface
    for scan in scans:
        if scan.view is not None:
            _carve_view(free, lattice, scan.view)
        elif scan.origin is not None:
            _carve(free, lattice, scan.origin, np.concatenate([scan.hits, scan.free_ends]), stop)
        flat, inside = lattice.index(scan.hits)
        occupied[flat[inside]] = True
    state = np.where(occupied, OCCUPIED, np.where(free, FREE, UNKNOWN)).astype(np.int8)
    if known_free is not None:
        unknown = np.flatnonzero(state == UNKNOWN)
        state[unknown[np.asarray(known_free(lattice.centres(unknown)), dtype=bool)]] = FREE
    return state.reshape(lattice.shape)


def signed_distance(occupied: np.ndarray, spacing) -> np.ndarray:
    """(X, Y, Z) bool occupancy -> (X, Y, Z) float signed distance (metres, negative inside) by two EDTs.

    Without any occupied voxel every value is the volume's diagonal (no obstacle within it); with no free
    voxel, minus that."""
    spacing = np.asarray(spacing, dtype=np.float64)
    cap = float(np.linalg.norm(np.asarray(occupied.shape) * spacing))
    if not occupied.any():
        return np.full(occupied.shape, cap)
    if occupied.all():
        return np.full(occupied.shape, -cap)
    outside = distance_transform_edt(~occupied, sampling=spacing)  # to the nearest occupied voxel
    inside = distance_transform_edt(occupied, sampling=spacing)  # to the nearest free voxel
    # An occupied voxel next to free space is a surface voxel (0); k voxels deeper reads about -k voxels.
    return np.where(occupied, -(inside - spacing.min()), outside)


def _share(part: int, whole: int) -> str:
    return f"{part} of {whole} points ({part / whole:.1%})"


def checked_scans(scans: list[Scan], lattice: Lattice, padding: float,
                  known_free: Callable[[np.ndarray], np.ndarray] | None = None) -> list[Scan]:
    """The scans, after checking that they can describe the workspace: no points, or (almost) none inside
    the bounds + padding (millimetres, another frame) are errors; points dropped outside it and points on
    the robot's own volume are warnings with their share. Without these checks such clouds silently
    become "no obstacle anywhere". (A `Scan` holds finite points only; `load_point_cloud` drops the others
    with a warning and refuses a cloud of nothing else.)"""
    total = sum(len(s.hits) for s in scans)
    if total == 0:
        raise ValueError("the scans hold no points: a reconstruction from them would be an empty world (no obstacle "
                         "anywhere). Check that the sensor returned data and the cloud file is the right one")
    hits = np.concatenate([s.hits for s in scans])  # (N, 3) finite
    _, inside = lattice.index(hits)
    n_in, n = int(inside.sum()), len(hits)
    extent = float(np.ptp(hits, axis=0).max())
    where = (f"the points span {np.round(hits.min(0), 3).tolist()} to {np.round(hits.max(0), 3).tolist()} m, the "
             f"workspace bounds are {[list(b) for b in lattice.bounds]} m (+ {padding} m padding)")
    hint = (f"The cloud is {extent:.0f} units wide: if it is in millimetres, scale it by 0.001" if extent > MILLIMETRES
            else "If the cloud is in another frame (the sensor's), give its sensor -> base transform "
                 "(scan_from_file(..., transform=T)) or fix the extrinsics")
    if n_in < max(MIN_INSIDE, MIN_INSIDE_SHARE * n):
        raise ValueError(f"only {_share(n_in, n)} lie inside the workspace: {where}. {hint}")
    if n - n_in > WARN_OUTSIDE_SHARE * n:
        warnings.warn(f"{_share(n - n_in, n)} lie outside the workspace and are dropped: {where}. Expected when the "
                      f"bounds are tighter than the scene. {hint}", stacklevel=3)
    if known_free is not None:
        on_robot = int(np.asarray(known_free(hits[inside]), dtype=bool).sum())
        if on_robot > WARN_ON_ROBOT_SHARE * n_in:
            warnings.warn(f"{_share(on_robot, n_in)} inside the workspace lie on the robot's own volume, which the "
                          f"cameras cannot see as an obstacle: the cloud is probably shifted or in another frame "
                          f"({where}). {hint}", stacklevel=3)
    return scans


@dataclass
class Reconstruction:
    """A reconstructed anchor grid and what it was made from.

    Attributes:
        grid: (n_e, n_e, n_e) float32 tensor, signed distances at the anchors, indexed (x, y, z).
        state: (n_e, n_e, n_e) int8 voxel states at the anchors (UNKNOWN / FREE / OCCUPIED), before the policy.
        unknown: the policy applied to unknown voxels; points: surface points used.
    """

    grid: torch.Tensor
    state: np.ndarray
    unknown: str
    points: int

    @property
    def unknown_fraction(self) -> float:
        return float((self.state == UNKNOWN).mean())


def reconstruct_grid(scans: Sequence[Scan], n_e: int, bounds, unknown: str = "free", padding: float = 0.1,
                     known_free: Callable[[np.ndarray], np.ndarray] | None = None) -> Reconstruction:
    """The anchor grid (n_e, bounds) of the scene the `scans` observed.

    Args:
        scans: `Scan`s in the robot base frame (e.g. `World.capture` or `scan_from_file`).
        n_e: anchors per axis; bounds: ((xmin, ymin, zmin), (xmax, ymax, zmax)), as the exact grid's.
        unknown: "free" or "occupied": what voxels no camera saw free become (inside the bounds).
        padding: metres of volume beyond the bounds on every side (obstacles there still count).
        known_free: (N, 3) points -> (N,) bool, space known to be free (e.g. the robot's own volume).
    """
    if unknown not in UNKNOWN_POLICIES:
        raise ValueError(f"unknown must be one of {UNKNOWN_POLICIES} (what unobserved space becomes), got {unknown!r}")
    scans = list(scans)
    if not scans or not all(isinstance(s, Scan) for s in scans):
        raise ValueError("reconstruct_grid needs one or more samp.perception.Scan observations")
    if unknown == "occupied" and all(s.origin is None for s in scans):
        raise ValueError("no scan has a sensor origin, so no space is observed free and unknown='occupied' would "
                         "fill the whole workspace; give the sensor position (origin=[x, y, z]) or use unknown='free'")
    lattice = Lattice.make(n_e, bounds, padding)
    scans = checked_scans(scans, lattice, padding, known_free)
    state = observe(scans, lattice, known_free)
    occupied = state == OCCUPIED
    if unknown == "occupied":  # within the bounds only: the padding is there for measured surfaces
        lattice.crop(occupied)[...] |= lattice.crop(state) == UNKNOWN
    sdf = lattice.crop(signed_distance(occupied, lattice.spacing))
    return Reconstruction(torch.from_numpy(np.ascontiguousarray(sdf, dtype=np.float32)),
                          np.ascontiguousarray(lattice.crop(state)), unknown, sum(len(s.hits) for s in scans))


def reconstruction_error(grid, exact, near: float = NEAR) -> dict[str, float]:
    """Errors of a reconstructed grid against the exact one, both (n_e, n_e, n_e), in millimetres:
    MAE and max over anchors near obstacles (|exact| < near), MAE over all anchors, and the fraction of
    near anchors whose sign is opposite (a 0 on the surface is not counted)."""
    grid, exact = (np.asarray(g, dtype=np.float64) for g in (grid, exact))
    if grid.shape != exact.shape:
        raise ValueError(f"grids differ in shape: reconstructed {grid.shape}, exact {exact.shape}")
    err = np.abs(grid - exact)
    mask = np.abs(exact) < near
    if not mask.any():
        return {"mae_near_mm": float("nan"), "max_near_mm": float("nan"), "mae_all_mm": 1e3 * float(err.mean()),
                "sign_error_near": float("nan"), "near_anchors": 0}
    return {"mae_near_mm": 1e3 * float(err[mask].mean()), "max_near_mm": 1e3 * float(err[mask].max()),
            "mae_all_mm": 1e3 * float(err.mean()),
            "sign_error_near": float((grid[mask] * exact[mask] < 0).mean()),
            "near_anchors": int(mask.sum())}
