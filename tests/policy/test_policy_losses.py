"""The losses of docs/design.md section 4 against hand-computed values and the exact scene SDF."""

from __future__ import annotations

import math

import pytest
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


def test_demo_margin_asks_only_for_the_demonstrations_clearance_up_to_d_margin():
    """margin="demo": m_i = min(d_margin, C*_i), C*_i the SDF at the demonstrated point. On a linear SDF
    (sdf = z - 0.5, exact under trilinear interpolation) with hand-computed hinges: a demonstration 2 cm
    from the obstacle asks the prediction (1 cm) for 1 cm more, not the fixed 8 cm; one 20 cm away asks
    for d_margin; a prediction clearer than its demonstration costs nothing."""
    z = torch.linspace(0.0, 1.0, 5)
    grid = (z - 0.5).expand(5, 5, 5).clone()[None]
    bounds = ((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0))
    pred = torch.tensor([[[0.0, 0.0, 0.51], [0.0, 0.0, 0.52], [0.0, 0.0, 0.56]]])  # clearance 1, 2 and 6 cm
    true = torch.tensor([[[0.0, 0.0, 0.52], [0.0, 0.0, 0.70], [0.0, 0.0, 0.53]]])  # clearance 2, 20 and 3 cm
    d_robot = torch.full((1, 3), 0.015)  # weight 1
    demo = LossConfig(d_margin=0.09, margin="demo")
    got = collision_loss(pred, grid, torch.tensor([0]), bounds, d_robot, demo, true)
    torch.testing.assert_close(got, torch.tensor((0.01 + 0.07 + 0.0) / 3), rtol=0, atol=1e-6)
    fixed = collision_loss(pred, grid, torch.tensor([0]), bounds, d_robot, LossConfig(d_margin=0.09), true)
    torch.testing.assert_close(fixed, torch.tensor((0.08 + 0.07 + 0.03) / 3), rtol=0, atol=1e-6)
    with pytest.raises(ValueError, match="true_points"):
        collision_loss(pred, grid, torch.tensor([0]), bounds, d_robot, demo)
    with pytest.raises(ValueError, match="loss.margin must be one of"):
        LossConfig(margin="adaptive")


def test_collision_loss_gradient_pushes_points_out():
    scene = Scene("box", obstacles=(Box("b", (0.4, 0.4, 0.4), Pose((0.5, 0.0, 0.5))),), bounds=BOUNDS)
    grid = scene.anchor_grid(61, cache=False)
    pts = torch.tensor([[[0.27, 0.0, 0.5]]], requires_grad=True)  # left of the box, within the margin
    collision_loss(pts, grid[None], torch.tensor([0]), BOUNDS, torch.zeros(1, 1), LossConfig()).backward()
    assert pts.grad[0, 0, 0] > 0  # descending the gradient moves the point in -x, away from the box



@pytest.mark.parametrize("margin", ["fixed", "demo"])
def test_collision_loss_differentiated_at_active_points_equals_the_dense_hinge(margin):
    """`collision_loss` reads the grid with a graph only where the hinge acts; the oracle is the dense
    formula of docs/design.md section 4 (trilinear at every point, hinge, per-point weights, mean). Two scenes, points
    near and far from their obstacles: the loss and the gradients at the points must be equal bit for bit
    (each point's trilinear value does not depend on which others are sampled with it)."""
    from samp.policy.network import sample_by_scene

    scenes = [Scene("box", obstacles=(Box("b", (0.4, 0.4, 0.4), Pose((0.5, 0.0, 0.5))),), bounds=BOUNDS),
              Scene("low", obstacles=(Box("c", (0.6, 0.6, 0.2), Pose((-0.3, 0.2, 0.3))),), bounds=BOUNDS)]
    grids = torch.stack([s.anchor_grid(21, cache=False) for s in scenes])
    g = torch.Generator().manual_seed(5)
    lo, hi = torch.tensor(BOUNDS[0]), torch.tensor(BOUNDS[1])
    pts = lo + (hi - lo) * torch.rand(6, 200, 3, generator=g)
    true = pts + 0.02 * torch.randn(pts.shape, generator=g)
    scene = torch.tensor([1, 0, 1, 1, 0, 0])
    d_robot = 0.05 * torch.rand(6, 200, generator=g)
    cfg = LossConfig(margin=margin, d_margin=0.2)

    def dense(p):
        env = sample_by_scene(grids[:, None], scene, p, BOUNDS)[:, 0]
        m = (sample_by_scene(grids[:, None], scene, true, BOUNDS)[:, 0].clamp(max=cfg.d_margin) if margin == "demo"
             else cfg.d_margin)
        return (torch.exp(-(d_robot - cfg.d_target) / cfg.tau) * torch.relu(m - env)).mean()

    got_p, want_p = pts.clone().requires_grad_(), pts.clone().requires_grad_()
    got = collision_loss(got_p, grids, scene, BOUNDS, d_robot, cfg, true)
    want = dense(want_p)
    got.backward()
    want.backward()
    active = (want_p.grad != 0).any(dim=-1)
    assert 0 < int(active.sum()) < active.numel(), "the test needs both active and inactive points"
    assert torch.equal(got, want), f"loss: expected {float(want)!r}, got {float(got)!r}"
    assert torch.equal(got_p.grad, want_p.grad), \
        f"gradients differ by up to {float((got_p.grad - want_p.grad).abs().max()):.3e}"
    with torch.no_grad():  # no graph: the same value
        assert torch.equal(collision_loss(pts, grids, scene, BOUNDS, d_robot, cfg, true), want.detach())


def _step(robot_sdf_calls: list):
    """A StepPrediction with a linear environment SDF; `robot_sdf_calls` counts the robot SDF queries."""
    from samp.policy.losses import StepPrediction

    z = torch.linspace(0.0, 1.0, 5)
    grid = (z - 0.5).expand(5, 5, 5).clone()[None]  # sdf = z - 0.5, exact under trilinear interpolation
    pred = torch.tensor([[[0.0, 0.0, 0.55], [0.0, 0.0, 0.5]]])  # sdf 0.05 and 0
    true = pred + torch.tensor([0.1, 0.0, 0.0])

    def robot_sdf(needed):
        robot_sdf_calls.append(needed)
        return torch.full((1, 2), 0.015)  # d_target: weight exp(0) = 1

    return StepPrediction(torch.tensor([[0.0, 1.0]]), torch.tensor([[0.5, 1.0]]), pred, true, grid,
                          torch.zeros(1, dtype=torch.long), ((-1.0, -1.0, 0.0), (1.0, 1.0, 1.0)), robot_sdf)


def test_loss_terms_weigh_each_term_by_its_config_field():
    import pytest

    from samp.policy.losses import loss_terms

    calls = []
    out = loss_terms(_step(calls), LossConfig(match=2.0, collision=10.0, config=3.0, d_margin=0.09))
    match = 0.1 / 3 + 0.01 / 3  # |dx| = 0.1 in one of three coordinates, at both points
    coll = ((0.09 - 0.05) + (0.09 - 0.0)) / 2
    config = 0.25
    assert math.isclose(out["match"], match, rel_tol=1e-5) and math.isclose(out["coll"], coll, rel_tol=1e-5)
    assert math.isclose(out["config"], config, rel_tol=1e-6)
    assert math.isclose(out["loss"], 2.0 * match + 10.0 * coll + 3.0 * config, rel_tol=1e-5)
    assert len(calls) == 1 and calls[0].tolist() == [[True, True]], "queried once, for the points where the hinge acts"
    calls.clear()
    off = loss_terms(_step(calls), LossConfig(match=2.0, collision=10.0, config=3.0), off=("coll",))
    assert float(off["coll"]) == 0.0 and calls == [] and math.isclose(off["loss"], 2.0 * match + 3.0 * config, rel_tol=1e-5)
    with pytest.raises(ValueError, match=r"unknown loss term\(s\) \['colision'\]"):
        loss_terms(_step(calls), LossConfig(), off=("colision",))


def test_a_new_loss_term_is_one_entry(monkeypatch):
    """What adding a term takes: one LossTerm in LOSS_TERMS (and its weight field in LossConfig)."""
    import dataclasses

    import samp.policy.losses as losses

    Config = dataclasses.make_dataclass("Config", [("smooth", float, 0.5)], bases=(LossConfig,))
    term = losses.LossTerm("smooth", "smooth", lambda s, c: (s.q_hat - s.q_next).abs().sum())
    monkeypatch.setattr(losses, "LOSS_TERMS", (*losses.LOSS_TERMS, term))
    out = losses.loss_terms(_step([]), Config())
    assert math.isclose(out["smooth"], 0.5) and math.isclose(out["loss"] - out["match"] - 20 * out["coll"]
                                                               - out["config"], 0.25, rel_tol=1e-5)
