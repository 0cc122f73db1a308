"""PointNet++ set abstraction in plain torch (Qi et al., "PointNet++", NeurIPS 2017), for the MPiNet-style
baseline. No custom CUDA kernels: every operation is a batched tensor operation, so it runs on the CPU
and on a GPU alike (slower than the fused kernels of the original, which is fine at our point counts).

    farthest_point_sample(xyz, k)              (B, N, 3) -> (B, k) indices, greedy farthest-first from index 0
    ball_query(xyz, centres, radius, k)        -> (B, S, k) indices: the first k points (in index order)
                                                  within `radius` of each centre, padded with the first one
    SetAbstraction                             sample centres, group their balls, shared MLP, max-pool
    PointNet2Encoder                           a stack of set abstractions ending in a global one

Ball query follows the original's convention (first k in index order, not the k nearest), which keeps it
a fixed-size, deterministic grouping; a centre whose ball is empty (possible only for centres that are
not points of the set) takes its nearest point instead.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

__all__ = ["PointNet2Encoder", "SALevel", "SetAbstraction", "ball_query", "farthest_point_sample", "gather_points"]


def farthest_point_sample(xyz: torch.Tensor, k: int, start: int = 0) -> torch.Tensor:
    """Greedy farthest point sampling.

    Args: xyz (B, N, 3); k points to pick (1 <= k <= N); start: the index picked first.
    Returns: (B, k) long indices; pick i+1 is the point farthest from picks 0..i (first index on ties).
    """
    if xyz.dim() != 3 or xyz.shape[-1] != 3:
        raise ValueError(f"xyz must be (B, N, 3), got {tuple(xyz.shape)}")
    B, N, _ = xyz.shape
    if not 1 <= k <= N or not 0 <= start < N:
        raise ValueError(f"need 1 <= k <= N and 0 <= start < N, got k={k}, start={start}, N={N}")
    rows = torch.arange(B, device=xyz.device)
    picks = torch.empty(B, k, dtype=torch.long, device=xyz.device)
    nearest = torch.full((B, N), float("inf"), dtype=xyz.dtype, device=xyz.device)  # distance to the picked set
    last = torch.full((B,), start, dtype=torch.long, device=xyz.device)
    for i in range(k):
        picks[:, i] = last
        d = (xyz - xyz[rows, last][:, None]).square().sum(-1)  # (B, N)
        nearest = torch.minimum(nearest, d)
        last = nearest.argmax(dim=-1)
    return picks


def ball_query(xyz: torch.Tensor, centres: torch.Tensor, radius: float, k: int) -> torch.Tensor:
    """Fixed-size neighbourhoods.

    Args: xyz (B, N, 3) the points; centres (B, S, 3); radius (metres); k neighbours per centre.
    Returns: (B, S, k) long indices into xyz: the points with |x - c| <= radius in increasing index order,
        the first of them repeated when fewer than k lie inside; the nearest point when none does.
    """
    if xyz.dim() != 3 or centres.dim() != 3 or xyz.shape[0] != centres.shape[0]:
        raise ValueError(f"expected xyz (B, N, 3) and centres (B, S, 3), got {tuple(xyz.shape)} and {tuple(centres.shape)}")
    if radius <= 0 or k < 1:
        raise ValueError(f"radius must be positive and k >= 1, got radius={radius}, k={k}")
    N = xyz.shape[1]
    # Exact differences (not the matrix-product shortcut), so points on the sphere are judged consistently.
    d2 = torch.cdist(centres, xyz, compute_mode="donot_use_mm_for_euclid_dist").square()  # (B, S, N)
    index = torch.arange(N, device=xyz.device).expand_as(d2)
    order = torch.where(d2 <= radius * radius, index, N)  # points outside read as N, after every inside one
    first = order.topk(min(k, N), dim=-1, largest=False, sorted=True).values  # (B, S, min(k, N))
    if k > N:
        first = torch.cat([first, first.new_full((*first.shape[:2], k - N), N)], dim=-1)
    head = torch.where(first[..., :1] < N, first[..., :1], d2.argmin(dim=-1, keepdim=True))  # (B, S, 1)
    return torch.where(first < N, first, head)


def gather_points(values: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """values (B, N, C), index (B, ...) -> (B, ..., C): values[b, index[b, ...]]."""
    rows = torch.arange(values.shape[0], device=values.device).view(-1, *([1] * (index.dim() - 1)))
    return values[rows, index]


def _shared_mlp(widths: list[int]) -> nn.Sequential:
    layers: list[nn.Module] = []
    for a, b in zip(widths[:-1], widths[1:]):
        layers += [nn.Linear(a, b), nn.LayerNorm(b), nn.ReLU()]
    return nn.Sequential(*layers)


class SetAbstraction(nn.Module):
    """One PointNet++ level: `centres` centres by farthest point sampling, a ball of `neighbours` points
    of radius `radius` around each, a shared MLP over [relative xyz / radius, features] and a max over
    each ball. With `centres` None it is the global level: one set of every point, absolute xyz."""

    def __init__(self, centres: int | None, radius: float | None, neighbours: int | None, in_features: int,
                 widths: list[int]):
        super().__init__()
        if centres is not None and (radius is None or neighbours is None):
            raise ValueError("a local set abstraction needs a radius and a neighbour count")
        self.centres, self.radius, self.neighbours = centres, radius, neighbours
        self.mlp = _shared_mlp([3 + in_features, *widths])
        self.out_features = widths[-1]

    def forward(self, xyz: torch.Tensor, features: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """xyz (B, N, 3), features (B, N, C) -> centres (B, S, 3), their features (B, S, C_out); S = 1 globally."""
        if self.centres is None:
            pooled = self.mlp(torch.cat([xyz, features], dim=-1)).amax(dim=1, keepdim=True)  # (B, 1, C_out)
            return xyz.new_zeros(xyz.shape[0], 1, 3), pooled
        if self.centres > xyz.shape[1]:
            raise ValueError(f"set abstraction asks for {self.centres} centres from only {xyz.shape[1]} points")
        with torch.no_grad():  # indices only: nothing to differentiate
            centre_idx = farthest_point_sample(xyz, self.centres)  # (B, S)
            centres = gather_points(xyz, centre_idx)  # (B, S, 3)
            ball = ball_query(xyz, centres, self.radius, self.neighbours)  # (B, S, k)
        local = (gather_points(xyz, ball) - centres[:, :, None]) / self.radius  # (B, S, k, 3)
        grouped = torch.cat([local, gather_points(features, ball)], dim=-1)  # (B, S, k, 3 + C)
        return centres, self.mlp(grouped).amax(dim=2)


@dataclass
class SALevel:
    """One local level of `PointNet2Encoder` (a config node: centres, radius in metres, neighbours, widths)."""

    centres: int = 128
    radius: float = 0.1
    neighbours: int = 16
    widths: list[int] = field(default_factory=lambda: [32, 32, 64])


class PointNet2Encoder(nn.Module):
    """Local set abstractions (`levels`), then a global one (`global_widths`) -> one feature per cloud.

    forward(xyz (B, N, 3), features (B, N, C)) -> (B, global_widths[-1]).
    """

    def __init__(self, in_features: int, levels: list[SALevel | dict], global_widths: list[int]):
        super().__init__()
        layers, width = [], in_features
        for level in levels:
            lv = level if isinstance(level, SALevel) else SALevel(**level)
            layers.append(SetAbstraction(lv.centres, lv.radius, lv.neighbours, width, list(lv.widths)))
            width = layers[-1].out_features
        layers.append(SetAbstraction(None, None, None, width, list(global_widths)))
        self.levels = nn.ModuleList(layers)
        self.out_features = layers[-1].out_features

    def forward(self, xyz: torch.Tensor, features: torch.Tensor) -> torch.Tensor:
        for level in self.levels:
            xyz, features = level(xyz, features)
        return features[:, 0]
