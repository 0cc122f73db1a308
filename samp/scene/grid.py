"""Anchor grids: the exact scene SDF on an (x, y, z)-indexed lattice, and sampling it with grid_sample.

Anchors are `n_e` points per axis (inclusive linspace over the bounds), array index order (x, y, z).
`torch.nn.functional.grid_sample` reads a (D, H, W) volume with coordinates in (W, H, D) order, so an
(x, y, z) volume takes coordinates (z, y, x): `grid_coords` is the one place that knows this.
"""

from __future__ import annotations

import functools
import hashlib
import json

import numpy as np
import torch
import torch.nn.functional as F

from samp.names import N_E_MAX
from samp.paths import cache_dir, write_cache_file
from samp.scene.model import Scene, check_bounds

__all__ = ["anchor_points", "check_n_e", "anchor_grid", "grid_coords", "sample_grid"]


def check_n_e(n_e) -> int:
    """`n_e` (anchors per axis) as an int, or ValueError unless it is an integer in [2, N_E_MAX]."""
    if not isinstance(n_e, (int, np.integer)) or isinstance(n_e, bool) or not 2 <= n_e <= N_E_MAX:
        raise ValueError(f"n_e (anchors per axis) must be an integer in [2, {N_E_MAX}], got {n_e!r}"
                         + (f" (a grid of {n_e}^3 anchors would need {4 * n_e ** 3 / 1e9:.3g} GB)"
                            if isinstance(n_e, int) and n_e > N_E_MAX else ""))
    return int(n_e)


def anchor_points(n_e: int, bounds, dtype=torch.float64) -> torch.Tensor:
    """(n_e, n_e, n_e, 3) anchor positions, indexed (x, y, z)."""
    n_e = check_n_e(n_e)
    lo, hi = check_bounds(bounds)
    axes = [torch.linspace(lo[i], hi[i], n_e, dtype=dtype) for i in range(3)]
    return torch.stack(torch.meshgrid(*axes, indexing="ij"), dim=-1)


def anchor_grid(scene: Scene, n_e: int, bounds=None, cache: bool = True) -> torch.Tensor:
    """(n_e, n_e, n_e) float32 exact signed distances at the anchors, cached on disk by
    (scene hash, n_e, bounds)."""
    n_e = check_n_e(n_e)
    bounds = check_bounds(scene.bounds if bounds is None else bounds)
    key = hashlib.sha256(json.dumps([scene.content_hash(), n_e, bounds]).encode()).hexdigest()[:24]
    path = cache_dir("anchor_grids") / f"{key}.npy"
    if cache and path.is_file():
        return torch.from_numpy(np.load(path))
    # float32 throughout: the grid is stored in float32, and it halves the memory traffic of 160^3 x K.
    grid = torch.stack([scene.sdf(plane) for plane in anchor_points(n_e, bounds, dtype=torch.float32)])  # x-slabs
    if cache:
        write_cache_file(path, lambda f: np.save(f, grid.numpy()))
    return grid


def grid_coords(points: torch.Tensor, bounds) -> torch.Tensor:
    """(..., 3) base-frame points -> (..., 3) grid_sample coordinates in [-1, 1], ordered (z, y, x)."""
    try:
        key = tuple(tuple(float(v) for v in row) for row in (bounds.tolist() if torch.is_tensor(bounds) else bounds))
    except (TypeError, ValueError):
        key = check_bounds(bounds)  # raises, saying what bounds must be
    lo, span = _checked(key)
    lo, span = (torch.tensor(v, dtype=points.dtype, device=points.device) for v in (lo, span))
    return (2 * (points - lo) / span - 1).flip(-1)


@functools.lru_cache(maxsize=256)
def _checked(bounds: tuple) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Bounds as float tuples -> checked (lo, hi - lo), once per bounds (a policy step samples the same ones
    every call)."""
    lo, hi = check_bounds(bounds)
    return lo, tuple(b - a for a, b in zip(lo, hi))


def sample_grid(grid: torch.Tensor, points: torch.Tensor, bounds) -> torch.Tensor:
    """Trilinear values of (x, y, z)-indexed grids at base-frame points.

    Args:
        grid: (n, n, n) one grid, or (B, C, n, n, n) a batch of C-channel volumes.
        points: (N, 3) with one grid, or (B, N, 3) with a batch.
    Returns:
        (N,) with one grid, or (B, C, N) with a batch. Points outside the bounds take the border value.
    """
    single = grid.dim() == 3
    vol = grid[None, None] if single else grid
    pts = points[None] if single else points
    if vol.dim() != 5 or pts.dim() != 3 or pts.shape[0] != vol.shape[0]:
        raise ValueError(f"expected grid (n, n, n) with points (N, 3), or grid (B, C, n, n, n) with points "
                         f"(B, N, 3); got {tuple(grid.shape)} and {tuple(points.shape)}")
    coords = grid_coords(pts.to(vol.dtype), bounds)[:, :, None, None, :]  # (B, N, 1, 1, 3)
    out = F.grid_sample(vol, coords, mode="bilinear", padding_mode="border", align_corners=True)  # (B, C, N, 1, 1)
    out = out[..., 0, 0]
    return out[0, 0] if single else out
