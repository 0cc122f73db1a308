"""SIMPNet-style sampling network (after "SIMPNet: Spatial-Informed Motion Planning Network", whose
learned sampler proposes configurations for a sampling-based planner), in plain torch.

SIMPNet reads the arm as a graph of joints and lets each joint attend to the obstacles. This network
keeps that structure on the anchor grid every method here receives:

    scene    anchor grid (S, n, n, n) -> 3D convolutions -> max-pooled to c^3 cells -> tokens (S, c^3, w)
             (each cell's features and its centre's coordinates, projected to width w)
    joints   node j: [u_t_j, u_g_j, u_g_j - u_t_j] -> linear + a learned embedding of joint j -> (B, n, w)
    rounds   message passing along the kinematic chain (each joint with its parent and child), then
             cross-attention of the joints to the scene tokens; residual, `rounds` times
    readout  per joint MLP with dropout -> du_j;  u_next = clamp(u_t + du, -1, 1)

Trained like MPNet's network (the next configuration of a demonstration, forward or backward), with
dropout kept on while sampling so repeated calls propose different states. What is not SIMPNet's: its
obstacles are geometric primitives given to the network, here the anchor grid; its exact layer sizes.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

__all__ = ["SIMPNetConfig", "SIMPNetNet"]


@dataclass
class SIMPNetConfig:
    """Architecture of `SIMPNetNet` (`conf/model/simpnet.yaml`)."""

    dof: int = 7
    channels: list[int] = field(default_factory=lambda: [8, 16, 32])  # 3D conv widths, each with stride 2
    cells: int = 4  # scene tokens per axis (cells^3 tokens)
    width: int = 64  # joint-node and token width
    heads: int = 4  # attention heads (width must divide by it)
    rounds: int = 2  # message-passing + attention rounds
    dropout: float = 0.3
    clip: float = 0.5  # grid distances are clipped to [-clip, clip] metres before encoding

    def __post_init__(self):
        if not 0.0 <= self.dropout < 1.0 or self.clip <= 0 or not self.channels or self.rounds < 1 or self.cells < 1:
            raise ValueError(f"SIMPNetConfig: dropout in [0, 1), clip > 0, channels non-empty, rounds and cells >= 1 "
                             f"expected; got {self.dropout}, {self.clip}, {self.channels}, {self.rounds}, {self.cells}")
        if self.width % self.heads:
            raise ValueError(f"SIMPNetConfig: width {self.width} must be a multiple of heads {self.heads}")


def _mlp(a: int, b: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(nn.Linear(a, b), nn.PReLU(), nn.Dropout(dropout))  # one slope: inputs are (B, n, width)


class SIMPNetNet(nn.Module):
    """Scene tokens + current and goal configurations -> next configuration (all normalised)."""

    def __init__(self, cfg: SIMPNetConfig):
        super().__init__()
        self.cfg = cfg
        layers, width = [], 1
        for c in cfg.channels:
            layers += [nn.Conv3d(width, c, 3, stride=2, padding=1), nn.PReLU(c)]
            width = c
        self.conv = nn.Sequential(*layers, nn.AdaptiveMaxPool3d(cfg.cells))
        self.tokens = nn.Linear(width + 3, cfg.width)
        centres = (torch.arange(cfg.cells) + 0.5) / cfg.cells * 2 - 1  # cell centres in [-1, 1]
        grid = torch.stack(torch.meshgrid(centres, centres, centres, indexing="ij"), dim=-1).reshape(-1, 3)
        self.register_buffer("centres", grid, persistent=False)  # (c^3, 3), (x, y, z) order as the cells
        self.node_in = nn.Linear(3, cfg.width)
        self.joint_embedding = nn.Parameter(torch.randn(cfg.dof, cfg.width) * 0.1)
        self.messages = nn.ModuleList(_mlp(3 * cfg.width, cfg.width, cfg.dropout) for _ in range(cfg.rounds))
        self.attention = nn.ModuleList(nn.MultiheadAttention(cfg.width, cfg.heads, batch_first=True)
                                       for _ in range(cfg.rounds))
        self.readout = nn.Sequential(_mlp(cfg.width, cfg.width, cfg.dropout), nn.Linear(cfg.width, 1))
        nn.init.zeros_(self.readout[-1].weight)  # du = 0 at first: the untrained sampler proposes "stay"
        nn.init.zeros_(self.readout[-1].bias)

    def encode(self, grids: torch.Tensor) -> torch.Tensor:
        """(S, n, n, n) grids indexed (x, y, z), metres -> (S, c^3, width) scene tokens."""
        if grids.dim() != 4:
            raise ValueError(f"grids must be (S, n, n, n), got {tuple(grids.shape)}")
        x = grids.clamp(-self.cfg.clip, self.cfg.clip)[:, None] / self.cfg.clip  # (S, 1, n, n, n)
        cells = self.conv(x).flatten(2).transpose(1, 2)  # (S, c^3, C), x slowest as `centres`
        return self.tokens(torch.cat([cells, self.centres.expand(len(cells), -1, -1)], dim=-1))

    def forward(self, tokens: torch.Tensor, u_t: torch.Tensor, u_g: torch.Tensor) -> torch.Tensor:
        """tokens (B, T, width), u_t and u_g (B, n) normalised -> (B, n) next configuration in [-1, 1]."""
        n = self.cfg.dof
        if tokens.dim() != 3 or tokens.shape[-1] != self.cfg.width or u_t.shape[-1] != n or u_t.shape != u_g.shape:
            raise ValueError(f"SIMPNetNet expects tokens (B, T, {self.cfg.width}) and u_t, u_g (B, {n}); got "
                             f"{tuple(tokens.shape)}, {tuple(u_t.shape)}, {tuple(u_g.shape)}")
        h = self.node_in(torch.stack([u_t, u_g, u_g - u_t], dim=-1)) + self.joint_embedding  # (B, n, w)
        for message, attend in zip(self.messages, self.attention):
            zero = torch.zeros_like(h[:, :1])
            parent, child = torch.cat([zero, h[:, :-1]], dim=1), torch.cat([h[:, 1:], zero], dim=1)  # chain neighbours
            h = h + message(torch.cat([parent, h, child], dim=-1))
            h = h + attend(h, tokens, tokens, need_weights=False)[0]
        u = u_t + self.readout(h)[..., 0]
        return u + (u.clamp(-1.0, 1.0) - u).detach()
