"""The unified robot SDF network (docs/design.md section 4): one hash grid and one MLP for all links.

Every link SDF network in this package has the same interface, so the whole-robot query
(`samp.robot_sdf.whole_robot.RobotSDF`) and the evaluation treat the method and its baselines alike:

    net(u (P, 3) points in their link's normalised box [-1, 1]^3, link (P,) int64) -> (P,) normalised distance

Here link i's box is moved by an offset t_i on a grid of spacing `spacing` (3 in the paper, so that the
boxes of half side 1 never overlap) and the whole layout is divided by its half extent D so that it
fills [-1, 1]^3; the encoder sees (u + t_i) / D mapped to [0, 1]^3. Layout "cube" puts the links on a
G x G x G grid (G the smallest with G^3 >= links: 3 for 8 to 27 links, so D = 4 as in the authors' code,
whose 3 x 3 plane also has D = 4); "plane" on G x G (G^2 >= links), the authors' arrangement.
"""

from __future__ import annotations

import inspect

import torch
from torch import nn

from samp.robot_sdf.encoding import HashGridEncoding

__all__ = ["LAYOUTS", "UnifiedHashSDF", "count_parameters", "link_offsets", "mlp"]

LAYOUTS = ("cube", "plane")


def link_offsets(num_links: int, spacing: float = 3.0, layout: str = "cube") -> tuple[torch.Tensor, float]:
    """(L, 3) offsets t_i on a centred grid and the half extent D of the layout (boxes included)."""
    if layout not in LAYOUTS:
        raise ValueError(f"layout must be one of {LAYOUTS}, got {layout!r}")
    if spacing < 2:
        raise ValueError(f"spacing must be >= 2 so that link boxes of half side 1 do not overlap, got {spacing}")
    dims = 3 if layout == "cube" else 2
    side = 1
    while side**dims < num_links:
        side += 1
    cells = torch.cartesian_prod(*[torch.arange(side, dtype=torch.float64)] * dims).reshape(-1, dims)[:num_links]
    offsets = torch.zeros(num_links, 3, dtype=torch.float64)
    offsets[:, :dims] = (cells - (side - 1) / 2) * spacing
    return offsets, spacing * (side - 1) / 2 + 1


def mlp(in_dim: int, hidden: list[int], out_dim: int = 1, activation: str = "relu") -> nn.Sequential:
    """Linear layers with `activation` between them (none after the last)."""
    act = {"relu": nn.ReLU, "softplus": lambda: nn.Softplus(beta=100), "silu": nn.SiLU}
    if activation not in act:
        raise ValueError(f"activation must be one of {sorted(act)}, got {activation!r}")
    dims, layers = [in_dim, *hidden, out_dim], []
    for i, (a, b) in enumerate(zip(dims[:-1], dims[1:])):
        layers.append(nn.Linear(a, b))
        if i < len(dims) - 2:
            layers.append(act[activation]())
    return nn.Sequential(*layers)


class UnifiedHashSDF(nn.Module):
    """Hash-grid encoder + MLP decoder over all links laid out side by side.

    Args:
        num_links: L, the robot's collision links.
        encoding: keyword arguments of `HashGridEncoding` (levels, features, log2_table_size, ...).
        hidden: widths of the decoder's hidden layers (the authors': [128, 128] after 32 x 2 = 64 features).
        spacing, layout: the link layout (module docstring).
    """

    label = "SAMP (hash grid)"

    def __init__(self, num_links: int, encoding: dict | None = None, hidden: list[int] | tuple = (128, 128),
                 spacing: float = 3.0, layout: str = "cube", activation: str = "relu"):
        super().__init__()
        if num_links < 1:
            raise ValueError(f"num_links must be >= 1, got {num_links}")
        self.num_links = num_links
        self.config = {"num_links": num_links, "encoding": dict(encoding or {}), "hidden": list(hidden),
                       "spacing": spacing, "layout": layout, "activation": activation}
        offsets, half_extent = link_offsets(num_links, spacing, layout)
        self.register_buffer("offsets", offsets.float())
        self.half_extent = half_extent
        encoding = dict(encoding or {})
        valid = [k for k in inspect.signature(HashGridEncoding).parameters]
        unknown = sorted(set(encoding) - set(valid))
        if unknown:
            raise ValueError(f"unknown hash-grid encoding key(s) {unknown}; valid keys: {', '.join(valid)}")
        self.encoder = HashGridEncoding(**encoding)
        self.decoder = mlp(self.encoder.out_dim, list(hidden), 1, activation)

    def unified(self, u: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
        """(P, 3) link-box points, (P,) link index -> (P, 3) encoder coordinates in [0, 1]^3."""
        return ((u + self.offsets.to(u.dtype)[link]) / self.half_extent + 1) / 2

    def forward(self, u: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
        """u (P, 3) in [-1, 1]^3, link (P,) -> (P,) distance in normalised units."""
        return self.decoder(self.encoder(self.unified(u, link))).squeeze(-1)

    def extra_repr(self) -> str:
        return f"num_links={self.num_links}, half_extent={self.half_extent:g}"


def count_parameters(module: nn.Module) -> int:
    return sum(p.numel() for p in module.parameters())
