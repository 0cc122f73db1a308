"""The policy's training losses, exactly as DESIGN section 4 ("Losses") defines them.

    L_match  = mean |T_q^(P) - T_q(P)| + mean (T_q^(P) - T_q(P))^2        (points in metres)
    L_coll   = (1/M) sum_i w_i max(0, d_margin - C_i),   w_i = exp(-(d_i - d_target) / tau)
    L_config = || q^_{t+1} - q_{t+1} ||^2                                   (radians, summed over joints)
    L        = lambda_1 L_match + lambda_2 L_coll + lambda_3 L_config

C_i is the environment SDF at the i-th posed point of the prediction, trilinear from the anchor grid;
d_i is the robot SDF at the same point, computed from the predicted joint angles in radians, and each
point gets its own weight (the authors' code multiplied mean weight by mean hinge instead, and fed the
robot SDF normalised angles; both are fixed here). The weights are treated as constants: they say how
much a point matters, and differentiating the robot SDF network through them would only add cost.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from samp.policy.network import sample_by_scene

__all__ = ["LossConfig", "collision_loss", "config_loss", "match_loss"]


@dataclass
class LossConfig:
    match: float = 1.0  # lambda_1
    collision: float = 20.0  # lambda_2
    config: float = 1.0  # lambda_3
    d_margin: float = 0.09  # metres
    d_target: float = 0.015  # metres
    tau: float = 1.0  # temperature of the per-point weights (1: the paper's)


def match_loss(pred_points: torch.Tensor, true_points: torch.Tensor) -> torch.Tensor:
    """(B, M, 3) both -> scalar: mean absolute plus mean squared coordinate difference."""
    diff = pred_points - true_points
    return diff.abs().mean() + diff.square().mean()


def collision_loss(pred_points: torch.Tensor, grids: torch.Tensor, scene_index: torch.Tensor, bounds,
                   robot_sdf: torch.Tensor, cfg: LossConfig) -> torch.Tensor:
    """pred_points (B, M, 3); grids (S, n, n, n) the scenes' anchor grids and scene_index (B,) into them;
    robot_sdf (B, M) metres -> scalar."""
    env = sample_by_scene(grids[:, None], scene_index, pred_points, bounds)[:, 0]  # (B, M)
    weights = torch.exp(-(robot_sdf.detach() - cfg.d_target) / cfg.tau)
    return (weights * torch.relu(cfg.d_margin - env)).mean()


def config_loss(q_pred: torch.Tensor, q_true: torch.Tensor) -> torch.Tensor:
    """(B, n) radians -> scalar: squared Euclidean distance, averaged over the batch."""
    return (q_pred - q_true).square().sum(dim=-1).mean()
