"""Pure-torch PointNet++ pieces against brute-force numpy loops: farthest point sampling, ball query,
set abstraction shapes, and the surface points an anchor grid yields (checked with the scene's exact SDF)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.policy.baselines.pointnet2 import PointNet2Encoder, SALevel, SetAbstraction, ball_query, farthest_point_sample


def _fps_reference(xyz: np.ndarray, k: int, start: int = 0) -> list[int]:
    """Farthest point sampling, one point and one candidate at a time."""
    picks = [start]
    for _ in range(k - 1):
        best, best_d = -1, -1.0
        for i, p in enumerate(xyz):
            d = min(float(np.sum((p - xyz[j]) ** 2)) for j in picks)
            if d > best_d:  # strictly greater: the first index wins ties
                best, best_d = i, d
        picks.append(best)
    return picks


def _ball_reference(xyz: np.ndarray, centre: np.ndarray, radius: float, k: int) -> list[int]:
    """The first k indices within radius, padded with the first; the nearest point if none is inside."""
    inside = [i for i, p in enumerate(xyz) if float(np.sum((p - centre) ** 2)) <= radius ** 2][:k]
    if not inside:
        inside = [int(np.argmin(np.sum((xyz - centre) ** 2, axis=1)))]
    return inside + [inside[0]] * (k - len(inside))


def test_farthest_point_sampling_matches_the_brute_force_loop():
    rng = np.random.default_rng(0)
    xyz = rng.uniform(-1, 1, size=(3, 60, 3))
    got = farthest_point_sample(torch.from_numpy(xyz), 12)
    for b in range(3):
        want = _fps_reference(xyz[b], 12)
        assert got[b].tolist() == want, f"batch {b}: expected {want}, got {got[b].tolist()}"
    assert farthest_point_sample(torch.from_numpy(xyz), 5, start=7)[0].tolist() == _fps_reference(xyz[0], 5, start=7)


def test_farthest_point_sampling_spreads_over_separated_clusters():
    clusters = torch.tensor([[0.0, 0, 0], [5, 0, 0], [0, 5, 0], [0, 0, 5]])
    xyz = (clusters[:, None] + 0.01 * torch.randn(4, 10, 3, generator=torch.Generator().manual_seed(1))).reshape(1, 40, 3)
    picks = farthest_point_sample(xyz, 4)[0]
    assert sorted((picks // 10).tolist()) == [0, 1, 2, 3], f"one pick per cluster expected, got {picks.tolist()}"


@pytest.mark.parametrize("radius, k", [(0.3, 8), (0.6, 32), (0.05, 4)])
def test_ball_query_matches_the_brute_force_loop(radius, k):
    rng = np.random.default_rng(1)
    xyz = rng.uniform(-1, 1, size=(2, 80, 3))
    centres = np.concatenate([xyz[:, :5], rng.uniform(-1.5, 1.5, size=(2, 5, 3))], axis=1)  # members and strangers
    got = ball_query(torch.from_numpy(xyz), torch.from_numpy(centres), radius, k)
    assert got.shape == (2, 10, k)
    for b in range(2):
        for s in range(10):
            want = _ball_reference(xyz[b], centres[b, s], radius, k)
            assert got[b, s].tolist() == want, f"batch {b} centre {s}: expected {want}, got {got[b, s].tolist()}"


def test_ball_query_with_more_neighbours_than_points():
    xyz = torch.tensor([[[0.0, 0, 0], [0.1, 0, 0], [2.0, 0, 0]]])
    got = ball_query(xyz, xyz[:, :1], 0.5, 5)
    assert got.tolist() == [[[0, 1, 0, 0, 0]]]


def test_bad_arguments_are_refused():
    xyz = torch.zeros(1, 4, 3)
    with pytest.raises(ValueError, match="1 <= k <= N"):
        farthest_point_sample(xyz, 5)
    with pytest.raises(ValueError, match="radius must be positive"):
        ball_query(xyz, xyz, 0.0, 2)
    with pytest.raises(ValueError, match="asks for 8 centres from only 4 points"):
        SetAbstraction(8, 0.1, 4, 0, [8])(xyz, xyz[..., :0])


def test_set_abstraction_and_encoder_shapes():
    torch.manual_seed(0)
    xyz, feats = torch.rand(2, 100, 3), torch.rand(2, 100, 3)
    centres, out = SetAbstraction(16, 0.3, 8, 3, [8, 12])(xyz, feats)
    assert centres.shape == (2, 16, 3) and out.shape == (2, 16, 12)
    enc = PointNet2Encoder(3, [SALevel(32, 0.2, 8, [16]), {"centres": 8, "radius": 0.5, "neighbours": 8, "widths": [24]}],
                           [32, 40])
    assert enc(xyz, feats).shape == (2, 40) and enc.out_features == 40


def test_the_global_feature_does_not_depend_on_the_order_of_the_points():
    """Invariant to any reordering that keeps farthest point sampling's first point, when every ball holds all
    the points within its radius (a ball of at most `neighbours` takes the first ones found, so truncated
    balls depend on the order). Catches features gathered from the wrong indices or pooled over the wrong
    axis; and moving one point must change the feature (it is not a constant)."""
    torch.manual_seed(0)
    xyz, feats = torch.rand(2, 100, 3), torch.rand(2, 100, 3)
    enc = PointNet2Encoder(3, [SALevel(32, 0.2, 100, [16]), SALevel(8, 0.5, 32, [24])], [32, 40]).eval()
    perm = torch.cat([torch.zeros(1, dtype=torch.long), 1 + torch.randperm(99)])
    with torch.no_grad():
        want, got = enc(xyz, feats), enc(xyz[:, perm], feats[:, perm])
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
        moved = xyz.clone()
        moved[:, 50] += 0.3
        assert (enc(moved, feats) - want).abs().max() > 1e-4, "moving a point must change the global feature"


def test_surface_points_lie_on_the_scene_surfaces():
    from samp.policy.baselines.mpinet import surface_points
    from samp.scene import generate_scene

    scene = generate_scene("tabletop", seed=0)
    grid = scene.anchor_grid(24, cache=False)
    points = surface_points(grid, scene.bounds, 300, seed=3)
    assert points.shape == (300, 3)
    assert torch.equal(points, surface_points(grid, scene.bounds, 300, seed=3)), "same seed, same points"
    d = scene.sdf(points.double()).abs()
    cell = (2.0 / 23) * 3 ** 0.5 / 2
    # Projection along the grid gradient lands on the surface except near edges and corners.
    assert float(d.median()) < 2e-3 and float(d.max()) < cell, f"median {float(d.median())}, max {float(d.max())}"
    lo, hi = torch.tensor(scene.bounds[0]), torch.tensor(scene.bounds[1])
    assert ((points >= lo - cell) & (points <= hi + cell)).all()
