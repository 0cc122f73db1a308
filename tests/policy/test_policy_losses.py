"""The losses of DESIGN section 4 against hand-computed values and the exact scene SDF."""

from __future__ import annotations

import math

import torch

from samp.policy import LossConfig, collision_loss, config_loss, match_loss
from samp.scene import Box, Pose, Scene

BOUNDS = ((-1.0, -1.0, 0.05), (1.0, 1.0, 1.25))


def test_match_loss_by_hand():
    a = torch.zeros(1, 2, 3)
    b = torch.tensor([[[0.1, 0.0, 0.0], [0.0, -0.2, 0.3]]])
    # |d|: 0.1, 0.2, 0.3 over 6 entries; d^2: 0.01, 0.04, 0.09 over 6 entries
    torch.testing.assert_close(match_loss(b, a), torch.tensor(0.6 / 6 + 0.14 / 6))


def test_config_loss_is_squared_norm_averaged_over_batch():
    q = torch.zeros(2, 3)
    q_hat = torch.tensor([[1.0, 2.0, 2.0], [0.0, 0.0, 1.0]])
    torch.testing.assert_close(config_loss(q_hat, q), torch.tensor((9.0 + 1.0) / 2))


def test_collision_loss_weights_each_point_and_uses_the_environment_sdf():
    """Two points, one deep near an obstacle and one far: the loss is the per-point weighted hinge,
    with C_i within a voxel's interpolation error of the exact SDF."""
    scene = Scene("box", obstacles=(Box("b", (0.4, 0.4, 0.4), Pose((0.5, 0.0, 0.5))),), bounds=BOUNDS)
    grid = scene.anchor_grid(81, cache=False)
    pts = torch.tensor([[[0.25, 0.0, 0.5], [-0.6, 0.0, 0.9]]])  # 0.05 m from the box; ~1 m from it
    d_robot = torch.tensor([[0.001, 0.06]])
    cfg = LossConfig(d_margin=0.09, d_target=0.015, tau=0.01)
    exact = scene.sdf(pts[0].double()).float()
    w = torch.exp(-(d_robot[0] - 0.015) / 0.01)
    expected = (w * torch.relu(0.09 - exact)).mean()
    got = collision_loss(pts, grid[None], torch.tensor([0]), BOUNDS, d_robot, cfg)
    torch.testing.assert_close(got, expected, rtol=0, atol=2e-3)
    assert math.isclose(float(expected), float(w[0] * (0.09 - exact[0]) / 2), rel_tol=1e-6)  # the far point adds 0
    # Per-point weighting differs from the authors' mean(weights) * mean(hinge):
    assert abs(float(got) - float(w.mean() * torch.relu(0.09 - exact).mean())) > 1e-3


def test_collision_loss_gradient_pushes_points_out():
    scene = Scene("box", obstacles=(Box("b", (0.4, 0.4, 0.4), Pose((0.5, 0.0, 0.5))),), bounds=BOUNDS)
    grid = scene.anchor_grid(61, cache=False)
    pts = torch.tensor([[[0.27, 0.0, 0.5]]], requires_grad=True)  # left of the box, within the margin
    collision_loss(pts, grid[None], torch.tensor([0]), BOUNDS, torch.zeros(1, 1), LossConfig()).backward()
    assert pts.grad[0, 0, 0] > 0  # descending the gradient moves the point in -x, away from the box
