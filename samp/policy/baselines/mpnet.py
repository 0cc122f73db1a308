"""MPNet-style networks (after Qureshi et al., "Motion Planning Networks", ICRA 2019 / T-RO 2020), plain torch.

    obstacle encoder   anchor grid (S, n, n, n) -> 3D convolutions -> pooled to 4^3 -> linear -> code (S, L)
    planning network   [code, u_t, u_g] -> MLP with dropout after every hidden layer -> u_next (B, n)

The planning network predicts the next configuration (normalised to [-1, 1]); it is parametrised as
u_t plus a learned offset, which is the same family of functions but starts from "stay" instead of from
noise. Dropout stays active while planning (`set_dropout(net, True)`), as MPNet does, so repeated
calls from the same state propose different next states: that is what replanning relies on.

MPNet pretrained a contractive autoencoder on obstacle point clouds; here the encoder reads the anchor
grid that every method in this project receives and is trained end to end with the planning network
(the T-RO paper's end-to-end variant).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
from torch import nn

__all__ = ["MPNetConfig", "MPNetNet", "ObstacleEncoder", "set_dropout"]


@dataclass
class MPNetConfig:
    """Architecture of `MPNetNet` (`conf/model/mpnet.yaml`)."""

    dof: int = 7
    channels: list[int] = field(default_factory=lambda: [8, 16, 32])  # 3D conv widths, each with stride 2
    code: int = 128  # obstacle code size
    hidden: list[int] = field(default_factory=lambda: [512, 256, 128, 64])  # planning MLP
    dropout: float = 0.5
    clip: float = 0.5  # grid distances are clipped to [-clip, clip] metres before encoding

    def __post_init__(self):
        if not 0.0 <= self.dropout < 1.0 or self.clip <= 0 or not self.channels or not self.hidden:
            raise ValueError(f"MPNetConfig: dropout in [0, 1), clip > 0 and non-empty channels and hidden expected; "
                             f"got dropout={self.dropout}, clip={self.clip}, channels={self.channels}, hidden={self.hidden}")


class ObstacleEncoder(nn.Module):
    """(S, n, n, n) grids indexed (x, y, z), metres -> (S, code). Any n >= 8."""

    def __init__(self, channels: list[int], code: int, clip: float):
        super().__init__()
        layers, width = [], 1
        for c in channels:
            layers += [nn.Conv3d(width, c, 3, stride=2, padding=1), nn.PReLU(c)]
            width = c
        self.conv = nn.Sequential(*layers, nn.AdaptiveMaxPool3d(4))
        self.head = nn.Linear(width * 4 ** 3, code)
        self.clip = clip

    def forward(self, grids: torch.Tensor) -> torch.Tensor:
        if grids.dim() != 4:
            raise ValueError(f"grids must be (S, n, n, n), got {tuple(grids.shape)}")
        x = grids.clamp(-self.clip, self.clip)[:, None] / self.clip  # (S, 1, n, n, n)
        return self.head(self.conv(x).flatten(1))


class MPNetNet(nn.Module):
    """Obstacle code + current and goal configurations -> next configuration (all normalised)."""

    def __init__(self, cfg: MPNetConfig):
        super().__init__()
        self.cfg = cfg
        self.encoder = ObstacleEncoder(cfg.channels, cfg.code, cfg.clip)
        layers, width = [], cfg.code + 2 * cfg.dof
        for h in cfg.hidden:
            layers += [nn.Linear(width, h), nn.PReLU(h), nn.Dropout(cfg.dropout)]
            width = h
        self.mlp = nn.Sequential(*layers, nn.Linear(width, cfg.dof))

    def encode(self, grids: torch.Tensor) -> torch.Tensor:
        """(S, n, n, n) -> (S, code)."""
        return self.encoder(grids)

    def forward(self, code: torch.Tensor, u_t: torch.Tensor, u_g: torch.Tensor) -> torch.Tensor:
        """code (B, L), u_t and u_g (B, n) normalised -> (B, n) next configuration, clamped to [-1, 1]."""
        if code.shape[-1] != self.cfg.code or u_t.shape[-1] != self.cfg.dof or u_t.shape != u_g.shape:
            raise ValueError(f"MPNetNet expects code (B, {self.cfg.code}) and u_t, u_g (B, {self.cfg.dof}); got "
                             f"{tuple(code.shape)}, {tuple(u_t.shape)}, {tuple(u_g.shape)}")
        u = u_t + self.mlp(torch.cat([code, u_t, u_g], dim=-1))
        return u + (u.clamp(-1.0, 1.0) - u).detach()


def set_dropout(net: nn.Module, active: bool) -> None:
    """Switch only the dropout layers of `net` on or off (the rest keeps its mode)."""
    for m in net.modules():
        if isinstance(m, nn.Dropout):
            m.train(active)
