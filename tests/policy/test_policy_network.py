"""SAMPNet: shapes, clamping, per-scene sampling against a per-sample oracle, gradients, ablations."""

from __future__ import annotations

import pytest
import torch

from samp.policy import PolicyConfig, SAMPNet, denormalize, normalize, sample_by_scene
from samp.policy.network import goal_features
from samp.scene.grid import sample_grid

BOUNDS = ((-1.0, -1.0, 0.05), (1.0, 1.0, 1.25))


def _points(B: int, M: int, seed: int = 0) -> torch.Tensor:
    g = torch.Generator().manual_seed(seed)
    return torch.rand(B, M, 3, generator=g) * torch.tensor([2.0, 2.0, 1.2]) + torch.tensor([-1.0, -1.0, 0.05])


def test_sample_by_scene_equals_sampling_each_sample_its_own_volume():
    g = torch.Generator().manual_seed(1)
    volumes = torch.randn(4, 3, 9, 10, 11, generator=g)
    scene = torch.tensor([2, 0, 2, 3, 3, 3, 0])
    pts = _points(7, 33)
    expected = sample_grid(volumes[scene], pts, BOUNDS)  # the straightforward per-sample gather
    torch.testing.assert_close(sample_by_scene(volumes, scene, pts, BOUNDS), expected, rtol=0, atol=1e-6)


def test_normalize_round_trip_and_range():
    limits = torch.tensor([[-2.9, 2.9], [-1.76, 1.76], [-3.07, -0.07]], dtype=torch.float64)
    q = torch.stack([limits[:, 0], limits[:, 1], limits.mean(1)])
    u = normalize(q, limits)
    torch.testing.assert_close(u, torch.tensor([[-1.0] * 3, [1.0] * 3, [0.0] * 3], dtype=torch.float64))
    torch.testing.assert_close(denormalize(u, limits), q)


def test_forward_shapes_clamp_and_parameter_count():
    cfg = PolicyConfig(dof=7, num_points=64)
    net = SAMPNet(cfg)
    grids = torch.randn(2, 12, 12, 12)
    feats = net.encode_scenes(grids)
    assert feats.shape == (2, 4, 5, 5, 5)  # conv stride 2: 6, then max-pool 2 with stride 1: 5
    u = torch.full((3, 7), 0.999)
    out = net(u, u, _points(3, 64), torch.rand(3, 64), feats, torch.tensor([0, 1, 1]), BOUNDS, n_e=12)
    assert out.shape == (3, 7) and out.abs().max() <= 1.0
    full = SAMPNet(PolicyConfig())
    assert 3.0e6 < sum(p.numel() for p in full.parameters()) < 3.5e6  # the paper: about 3.1 M


@pytest.mark.parametrize("env, points", [(True, True), (False, True), (True, False)])
def test_every_branch_gets_gradient(env, points):
    net = SAMPNet(PolicyConfig(dof=6, num_points=32, env_encoder=env, point_encoder=points))
    grids = torch.randn(2, 10, 10, 10)
    u = torch.rand(4, 6) * 0.5
    out = net(u, -u, _points(4, 32), torch.rand(4, 32), net.encode_scenes(grids), torch.tensor([0, 1, 0, 1]), BOUNDS, n_e=10)
    out.square().sum().backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, f"no gradient reaches {name}"
    assert hasattr(net, "env") == env and hasattr(net, "point_mlp") == points


def test_wrong_widths_are_clear_errors():
    net = SAMPNet(PolicyConfig(dof=7, num_points=16))
    feats = net.encode_scenes(torch.randn(1, 8, 8, 8))
    with pytest.raises(ValueError, match="built for 16 points and 7 joints"):
        net(torch.zeros(2, 6), torch.zeros(2, 6), _points(2, 16), torch.zeros(2, 16), feats, torch.zeros(2, dtype=torch.long), BOUNDS)


def test_goal_features_are_the_documented_functions_of_start_and_goal():
    u_t = torch.tensor([[0.0, 0.5, -0.5], [0.2, 0.2, 0.2]])
    u_g = torch.tensor([[0.3, 0.9, -0.5], [0.2, 0.2, 0.2]])  # second row: at the goal
    f = goal_features(u_t, u_g, extra=True)
    d = torch.tensor([[0.3, 0.4, 0.0], [0.0, 0.0, 0.0]])
    torch.testing.assert_close(f[:, :6], torch.cat([u_t, u_g], dim=1))
    torch.testing.assert_close(f[:, 6:9], d)
    torch.testing.assert_close(f[0, 9:12], torch.tensor([0.6, 0.8, 0.0]))  # unit direction of (0.3, 0.4, 0)
    torch.testing.assert_close(f[1, 9:12], torch.zeros(3))  # no NaN at the goal
    torch.testing.assert_close(f[:, 12], torch.tensor([0.5, 0.0]))
    torch.testing.assert_close(goal_features(u_t, u_g, extra=False), torch.cat([u_t, u_g], dim=1))


@pytest.mark.parametrize("B, M", [(5, 300), (9, 1024)])
def test_max_over_points_has_amax_values_and_gradients(B, M):
    """The PointNet's max through the winning points only (`max_over_points`) against amax over all points:
    the same values and the same parameter and input gradients (a wrong winner, a transposed diagonal or a
    missing point would change them). 9 x 1024 points go through the pass over every point in three chunks
    of whole samples (4, 4 and 1), 5 x 300 in one."""
    from samp.policy import network
    from samp.policy.network import _mlp, max_over_points

    torch.manual_seed(3)
    mlp = _mlp([4, 16, 32, 24])
    x = torch.randn(B, M, 4, requires_grad=True)
    w = torch.randn(B, 24)
    assert (B * M > network._CHUNK_POINTS) == (M == 1024)  # the second case is the chunked one
    grads = []
    for fn in (lambda: mlp(x).amax(dim=1), lambda: max_over_points(mlp, x)):
        mlp.zero_grad()
        x.grad = None
        out = fn()
        (out * w).sum().backward()
        grads.append((out.detach(), [p.grad.clone() for p in mlp.parameters()], x.grad.clone()))
    (a, pa, xa), (b, pb, xb) = grads
    torch.testing.assert_close(b, a, rtol=0, atol=1e-6)
    for u, v in zip(pa, pb):
        torch.testing.assert_close(v, u, rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(xb, xa, rtol=1e-5, atol=1e-6)
    with torch.no_grad():  # no autograd: the plain max
        assert torch.equal(max_over_points(mlp, x), mlp(x).amax(dim=1))


def test_first_argmax_is_argmax():
    """The blocked winner search (`first_argmax`) against torch's argmax, the oracle: random values, ties
    across and within blocks (argmax takes the first), NaN and inf (a NaN is the maximum), integer-valued
    ties everywhere, and a point count that is no multiple of the block."""
    from samp.policy.network import first_argmax

    torch.manual_seed(4)
    z = torch.randn(6, 256, 16)
    tied = z.clone()
    tied[:, 5] = tied[:, 6] = tied[:, 200] = 100.0  # one tie within a block, one across blocks
    tied[0, 3, 0], tied[1, 250, 1], tied[2, 40, 2] = float("nan"), float("nan"), float("inf")
    for name, v in {"random": z, "ties, NaN, inf": tied, "few values": torch.randint(0, 3, (4, 64, 8)).float(),
                    "M % 32 != 0": torch.randn(3, 100, 5)}.items():
        want, got = v.argmax(dim=1), first_argmax(v)
        assert torch.equal(got, want), f"{name}: expected argmax {want.tolist()}, got {got.tolist()}"
