"""Anchor grids: the axis convention, trilinear sampling against the exact SDF, and the disk cache."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.scene import Scene, anchor_points, generate_scene, grid_coords, sample_grid

BOUNDS = ((-1.0, -0.8, 0.05), (1.0, 1.2, 1.25))  # unequal spans, so a swapped axis cannot pass


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_grid_sample_reads_x_y_z_indexed_volumes(axis):
    """A grid holding one coordinate is read back exactly (trilinear is exact on linear functions)."""
    n = 7
    grid = anchor_points(n, BOUNDS)[..., axis]  # value = that coordinate, array indexed (x, y, z)
    pts = torch.as_tensor(np.random.default_rng(axis).uniform(BOUNDS[0], BOUNDS[1], (500, 3)))
    got = sample_grid(grid, pts, BOUNDS)
    assert torch.allclose(got, pts[:, axis], atol=1e-12), f"axis {axis}: max error {(got - pts[:, axis]).abs().max():.2e}"


def test_anchor_points_are_an_inclusive_linspace():
    a = anchor_points(5, BOUNDS)
    assert a.shape == (5, 5, 5, 3)
    assert torch.allclose(a[0, 0, 0], torch.tensor(BOUNDS[0], dtype=a.dtype))
    assert torch.allclose(a[-1, -1, -1], torch.tensor(BOUNDS[1], dtype=a.dtype))
    assert torch.allclose(a[2, 0, 0, 0], torch.tensor(0.0, dtype=a.dtype)) and a[2, 0, 0, 1] == BOUNDS[0][1]
    corners = grid_coords(torch.tensor([BOUNDS[0], BOUNDS[1]], dtype=torch.float64), BOUNDS)
    assert torch.equal(corners, torch.tensor([[-1.0] * 3, [1.0] * 3], dtype=torch.float64))


def _trilinear_bound(points: np.ndarray, n: int) -> np.ndarray:
    """Sum over the 8 cell corners of weight x distance to the point: a sound bound on the error of
    trilinear interpolation of any 1-Lipschitz function (independent of grid_sample)."""
    lo, hi = np.asarray(BOUNDS[0]), np.asarray(BOUNDS[1])
    h = (hi - lo) / (n - 1)
    u = (points - lo) / h
    i0 = np.clip(np.floor(u), 0, n - 2)
    f = u - i0
    bound = np.zeros(len(points))
    for corner in np.ndindex(2, 2, 2):
        c = np.asarray(corner)
        w = np.prod(np.where(c == 1, f, 1 - f), axis=1)
        bound += w * np.linalg.norm((i0 + c) * h + lo - points, axis=1)
    return bound


def test_trilinear_grid_matches_exact_sdf_within_resolution():
    scene = Scene.from_dict({**generate_scene("tabletop", seed=5).to_dict(), "bounds": [list(b) for b in BOUNDS]})
    n = 40
    grid = scene.anchor_grid(n, cache=False).double()
    pts = np.random.default_rng(6).uniform(BOUNDS[0], BOUNDS[1], (20_000, 3))
    got = sample_grid(grid, torch.as_tensor(pts), BOUNDS).numpy()
    exact = scene.sdf(pts)
    bound = _trilinear_bound(pts, n) + 1e-6  # + float32 storage of the grid
    worst = np.argmax(np.abs(got - exact) - bound)
    assert np.all(np.abs(got - exact) <= bound), (f"at {pts[worst]}: grid {got[worst]:.5f}, exact {exact[worst]:.5f}, "
                                                 f"bound {bound[worst]:.5f}")
    # With the axes swapped the same check fails: the test can tell the conventions apart.
    swapped = sample_grid(grid.permute(2, 1, 0).contiguous(), torch.as_tensor(pts), BOUNDS).numpy()
    assert np.any(np.abs(swapped - exact) > bound)


def test_batched_multichannel_sampling_matches_single():
    grid = anchor_points(9, BOUNDS).norm(dim=-1)
    pts = torch.as_tensor(np.random.default_rng(7).uniform(BOUNDS[0], BOUNDS[1], (2, 30, 3)))
    batch = torch.stack([grid, 2 * grid])[:, None].expand(2, 3, 9, 9, 9)  # (B, C, n, n, n)
    out = sample_grid(batch, pts, BOUNDS)
    assert out.shape == (2, 3, 30)
    assert torch.allclose(out[1, 2], 2 * sample_grid(grid, pts[1], BOUNDS))


def test_anchor_grid_is_cached_by_scene_resolution_and_bounds(tmp_path, monkeypatch):
    monkeypatch.setenv("SAMP_CACHE_DIR", str(tmp_path))
    scene = generate_scene("blocks", seed=1)
    first = scene.anchor_grid(12)
    files = sorted((tmp_path / "anchor_grids").glob("*.npy"))
    assert len(files) == 1 and first.dtype == torch.float32 and first.shape == (12, 12, 12)
    np.save(files[0], np.full((12, 12, 12), 7.0, dtype=np.float32))  # a cache hit returns the file
    assert torch.all(scene.anchor_grid(12) == 7.0)
    scene.anchor_grid(13)
    scene.anchor_grid(12, bounds=BOUNDS)
    assert len(list((tmp_path / "anchor_grids").glob("*.npy"))) == 3
    assert torch.equal(scene.anchor_grid(12, cache=False), first)


@pytest.mark.parametrize("n_e", [1, 0, -3, 2.5, True])
def test_bad_resolution(n_e):
    with pytest.raises(ValueError, match=r"n_e \(anchors per axis\) must be an integer in \[2, 256\]"):
        generate_scene("blocks", seed=0).anchor_grid(n_e)


def test_bad_bounds():
    with pytest.raises(ValueError, match=r"bounds need min < max on every axis"):
        generate_scene("blocks", seed=0).anchor_grid(8, bounds=((0, 0, 0), (1, 1, 0)))
    with pytest.raises(ValueError, match=r"bounds must be \(\(xmin, ymin, zmin\), \(xmax, ymax, zmax\)\)"):
        anchor_points(4, (0, 1))
