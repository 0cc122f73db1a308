"""MPiNet-style policy network (after Fishman et al., "Motion Policy Networks", CoRL 2022), in plain torch.

The input is one labelled point cloud per sample: robot points posed at q_t, obstacle points on the
scene's surfaces and target points (the robot posed at the goal configuration), each with a one-hot
label (robot, obstacle, target). A PointNet++ encodes the cloud; an MLP encodes the normalised q_t; a
decoder maps both to a normalised joint step:

    cloud (B, N_r + N_o + N_t, 3) + labels -> PointNet2Encoder -> F
    u_t (B, n)                             -> MLP              -> G
    [F, G] -> decoder -> du;  u_next = clamp(u_t + du, -1, 1)

Obstacle points come from the scene's anchor grid (`surface_points`): anchors within half a cell
diagonal of a surface, projected onto it along the grid's SDF gradient. The grid is what both training
(the DataModule) and the evaluation (`EnvBatch.grids`) hand over, so the policy sees the same points in
both; MPiNet itself samples its obstacle points from the scene meshes or a depth camera.
Point counts are configurable; the paper used 2048 robot, 4096 obstacle and 128 target points.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from samp.policy.baselines.pointnet2 import PointNet2Encoder, SALevel
from samp.scene.grid import anchor_points

__all__ = ["LABELS", "MPiNetConfig", "MPiNetNet", "even_subset", "labelled_cloud", "surface_points"]

LABELS = ("robot", "obstacle", "target")  # one-hot feature order of the point cloud


def _default_levels() -> list[SALevel]:
    return [SALevel(128, 0.1, 16, [32, 32, 64]), SALevel(32, 0.3, 16, [64, 128])]


@dataclass
class MPiNetConfig:
    """Architecture and point counts of `MPiNetNet` (`conf/model/mpinet.yaml`)."""

    dof: int = 7
    robot_points: int = 256  # N_r, on the robot's innermost shell (MPiNet: 2048)
    obstacle_points: int = 512  # N_o per scene (MPiNet: 4096)
    target_points: int = 128  # N_t, the robot posed at the goal (MPiNet: 128 gripper points)
    obstacle_seed: int = 0  # which surface points are drawn (the same for training and evaluation)
    levels: list[SALevel] = field(default_factory=_default_levels)  # local set abstractions
    global_widths: list[int] = field(default_factory=lambda: [128, 256])
    config_hidden: list[int] = field(default_factory=lambda: [64, 64])  # MLP over u_t
    decoder_hidden: list[int] = field(default_factory=lambda: [256, 128])

    def __post_init__(self):
        self.levels = [lv if isinstance(lv, SALevel) else SALevel(**lv) for lv in self.levels]
        counts = (self.robot_points, self.obstacle_points, self.target_points)
        if min(counts) < 1:
            raise ValueError(f"robot, obstacle and target point counts must be >= 1, got {counts}")
        if self.levels and self.levels[0].centres > sum(counts):
            raise ValueError(f"the first set abstraction samples {self.levels[0].centres} centres but the cloud has "
                             f"only {sum(counts)} points")


def even_subset(pool: torch.Tensor, count: int) -> torch.Tensor:
    """`count` entries of the index tensor `pool` (P,), evenly spread over it (deterministic); all of
    them, repeated evenly, when count > P."""
    if len(pool) == 0:
        raise ValueError("cannot pick points from an empty set")
    picks = torch.linspace(0, len(pool) - 1, count, dtype=torch.float64).round().long()
    return pool[picks.to(pool.device)]


def surface_points(grid: torch.Tensor, bounds, count: int, seed: int = 0) -> torch.Tensor:
    """Points on the obstacle surfaces of an anchor grid.

    Args: grid (n, n, n) exact signed distances indexed (x, y, z); bounds ((3,), (3,)) the grid spans.
    Returns: (count, 3) points: anchors within half a cell diagonal of a surface (every surface point has
        one that near), moved by -d * grad(d) onto the zero level set, then `count` of them drawn with a
        generator seeded by `seed` (with repeats only when fewer exist). A grid with no anchor that near
        a surface gives its anchor nearest to one, projected.
    """
    if grid.dim() != 3:
        raise ValueError(f"grid must be (n, n, n), got {tuple(grid.shape)}")
    n = grid.shape[0]
    anchors = anchor_points(n, bounds, dtype=grid.dtype).to(grid.device)  # (n, n, n, 3)
    lo, hi = (torch.as_tensor(b, dtype=grid.dtype, device=grid.device) for b in bounds)
    step = (hi - lo) / (n - 1)  # (3,) cell size per axis
    grad = torch.stack(torch.gradient(grid, spacing=step.tolist()), dim=-1)  # (n, n, n, 3) central differences
    unit = grad / grad.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    near = grid.abs() <= 0.5 * float(step.norm())
    if not near.any():
        near = grid.abs() == grid.abs().min()
    cand = anchors[near] - grid[near][:, None] * unit[near]  # (C, 3)
    g = torch.Generator().manual_seed(int(seed))
    pick = torch.randperm(len(cand), generator=g) if len(cand) >= count else torch.randint(len(cand), (count,), generator=g)
    return cand[pick[:count].to(cand.device)]


def labelled_cloud(robot: torch.Tensor, obstacles: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """robot (B, N_r, 3), obstacles (B, N_o, 3), target (B, N_t, 3) -> xyz (B, N, 3) and one-hot labels (B, N, 3)."""
    parts = (robot, obstacles, target)
    xyz = torch.cat(parts, dim=1)
    label = torch.cat([torch.full(p.shape[:2], i, dtype=torch.long, device=xyz.device) for i, p in enumerate(parts)], dim=1)
    return xyz, nn.functional.one_hot(label, len(LABELS)).to(xyz.dtype)


def _mlp(widths: list[int], last_activation: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(widths[:-1], widths[1:])):
        layers.append(nn.Linear(a, b))
        if last_activation or i < len(widths) - 2:
            layers.append(nn.ELU())
    return nn.Sequential(*layers)


class MPiNetNet(nn.Module):
    """Labelled point cloud + current configuration -> next normalised configuration. Pure torch."""

    def __init__(self, cfg: MPiNetConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = PointNet2Encoder(len(LABELS), cfg.levels, cfg.global_widths)
        self.config_mlp = _mlp([cfg.dof, *cfg.config_hidden])
        self.decoder = _mlp([self.encoder.out_features + cfg.config_hidden[-1], *cfg.decoder_hidden, cfg.dof],
                            last_activation=False)

    def forward(self, u_t: torch.Tensor, xyz: torch.Tensor, labels: torch.Tensor) -> torch.Tensor:
        """u_t (B, n) normalised; xyz (B, N, 3) metres; labels (B, N, 3) one-hot -> (B, n) in [-1, 1]."""
        if u_t.shape[-1] != self.cfg.dof or xyz.shape[:2] != labels.shape[:2] or labels.shape[-1] != len(LABELS):
            raise ValueError(f"MPiNetNet expects u_t (B, {self.cfg.dof}), xyz (B, N, 3) and labels (B, N, {len(LABELS)}); "
                             f"got {tuple(u_t.shape)}, {tuple(xyz.shape)}, {tuple(labels.shape)}")
        feature = torch.cat([self.encoder(xyz, labels), self.config_mlp(u_t)], dim=-1)
        u = u_t + self.decoder(feature)
        return u + (u.clamp(-1.0, 1.0) - u).detach()  # clamped in value, gradients pass (as SAMPNet)
