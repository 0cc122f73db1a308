"""MPiNet-style policy network (after Fishman et al., "Motion Policy Networks", CoRL 2022), in plain torch.

The input is one labelled point cloud per sample: robot points on the arm's surface posed at q_t,
obstacle points on the scene's surfaces and target points (the gripper posed at the goal end-effector
pose, as MPiNet's), each with a one-hot label (robot, obstacle, target); robot and target points come
from `samp.policy.baselines.mpinet_points`. A PointNet++ encodes the cloud; an MLP encodes the normalised q_t; a
decoder maps both to a normalised joint step:

    cloud (B, N_r + N_o + N_t, 3) + labels -> PointNet2Encoder -> F
    u_t (B, n)                             -> MLP              -> G
      (with `goal_config`, not MPiNet's: [u_t, u_g, u_g - u_t, its direction, its length] -> MLP -> G)
    [F, G] -> decoder -> du;  u_next = clamp(u_t + du, -1, 1)

The decoder's last layer starts at zero, so the untrained policy stands still (du = 0). With a default
initialisation the first steps of AdamW at lr 1e-3 threw du to the joint limits (|dq| ~ 5 rad against the
expert's 0.05 rad a step), where the point-match loss of a configuration that far off no longer points
back to the demonstration and training stalled there: the 0 % reach of the first Table I.

Obstacle points come from the scene's anchor grid (`surface_points`): anchors within half a cell
diagonal of a surface, projected onto it along the grid's SDF gradient. The grid is what both training
(the DataModule) and the evaluation (`EnvBatch.grids`) hand over, so the policy sees the same points in
both; MPiNet itself samples its obstacle points from the scene meshes or a depth camera.
Point counts are configurable: `conf/model/mpinet.yaml` is the CPU configuration, `conf/model/mpinet_paper.yaml`
MPiNet's own (2048 robot, 4096 obstacle and 128 target points and its set-abstraction sizes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

from samp.policy.baselines.pointnet2 import PointNet2Encoder, SALevel
from samp.scene.grid import anchor_points

__all__ = ["LABELS", "MPiNetConfig", "MPiNetNet", "labelled_cloud", "surface_points"]

LABELS = ("robot", "obstacle", "target")  # one-hot feature order of the point cloud


def _default_levels() -> list[SALevel]:
    return [SALevel(128, 0.1, 16, [32, 32, 64]), SALevel(32, 0.3, 16, [64, 128])]


@dataclass
class MPiNetConfig:
    """Architecture and point counts of `MPiNetNet` (`conf/model/mpinet.yaml`)."""

    dof: int = 7
    robot_points: int = 256  # N_r, on the arm's link surfaces (MPiNet: 2048)
    obstacle_points: int = 512  # N_o per scene (MPiNet: 4096)
    target_points: int = 128  # N_t, on the gripper posed at the goal (MPiNet: 128)
    obstacle_seed: int = 0  # which surface points are drawn (the same for training and evaluation)
    robot_seed: int = 0  # which robot and gripper surface points are drawn (fixed with the weights)
    goal_config: bool = False  # not MPiNet's: the joint MLP also sees the goal configuration, as SAMP's does
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


def _goal_terms(u_t: torch.Tensor, u_g: torch.Tensor) -> torch.Tensor:
    """(B, n) current and goal -> (B, 4n + 1) [u_t, u_g, d, d / |d|, |d|], d = u_g - u_t (SAMP's MLP_I input)."""
    d = u_g - u_t
    dist = d.norm(dim=-1, keepdim=True)
    return torch.cat([u_t, u_g, d, d / dist.clamp(min=1e-3), dist], dim=-1)


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
        self.config_mlp = _mlp([4 * cfg.dof + 1 if cfg.goal_config else cfg.dof, *cfg.config_hidden])
        self.decoder = _mlp([self.encoder.out_features + cfg.config_hidden[-1], *cfg.decoder_hidden, cfg.dof],
                            last_activation=False)
        nn.init.zeros_(self.decoder[-1].weight)  # du = 0 at first (module docstring)
        nn.init.zeros_(self.decoder[-1].bias)

    def forward(self, u_t: torch.Tensor, xyz: torch.Tensor, labels: torch.Tensor,
                u_g: torch.Tensor | None = None) -> torch.Tensor:
        """u_t (B, n) normalised; xyz (B, N, 3) metres; labels (B, N, 3) one-hot; u_g (B, n) normalised, read
        only with `goal_config` -> (B, n) in [-1, 1]."""
        if u_t.shape[-1] != self.cfg.dof or xyz.shape[:2] != labels.shape[:2] or labels.shape[-1] != len(LABELS):
            raise ValueError(f"MPiNetNet expects u_t (B, {self.cfg.dof}), xyz (B, N, 3) and labels (B, N, {len(LABELS)}); "
                             f"got {tuple(u_t.shape)}, {tuple(xyz.shape)}, {tuple(labels.shape)}")
        if self.cfg.goal_config and (u_g is None or u_g.shape != u_t.shape):
            raise ValueError(f"this MPiNetNet reads the goal configuration (goal_config): u_g (B, {self.cfg.dof}) expected, "
                             f"got {None if u_g is None else tuple(u_g.shape)}")
        joints = _goal_terms(u_t, u_g) if self.cfg.goal_config else u_t
        feature = torch.cat([self.encoder(xyz, labels), self.config_mlp(joints)], dim=-1)
        u = u_t + self.decoder(feature)
        return u + (u.clamp(-1.0, 1.0) - u).detach()  # clamped in value, gradients pass (as SAMPNet)
