"""The SAMP policy network, in plain torch (docs/design.md section 4, "Policy").

Inputs per sample: the current and goal configurations (normalised to [-1, 1] by the joint limits), the
scene's anchor grid, the M robot points posed at the current configuration, T_q(P), and the robot SDF
at those points. Four branches meet in a fusion MLP that predicts the normalised joint step:

    env      Phi_3D(grid) --grid_sample at T_q(P)--> (M, C) ++ robot SDF (M, 1) --flatten--> MLP_II -> 256
    points   PointNet over (xyz, d_robot) of T_q(P): shared MLP, max over points             -> 256
    config   MLP_I([q_t, q_g] + goal direction terms, see `goal_features`)                  -> 128
    fusion   MLP_III(640) -> dq;  q_next = clamp(q_t + dq, -1, 1) in normalised coordinates (the clamp
             passes gradients straight through, so predictions beyond a limit still learn)

Widths follow the authors' released code (about 3.1 M parameters with M = 1024, C = 4). `ablation`
switches remove the point encoder or the environment branch for the paper's ablations.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import torch
import torch.nn.functional as F
from torch import nn

from samp.scene.grid import sample_grid

__all__ = ["PolicyConfig", "SAMPNet", "denormalize", "first_argmax", "goal_features", "max_over_points", "normalize",
           "sample_by_scene"]


@dataclass
class PolicyConfig:
    """Architecture of `SAMPNet` (`conf/model/samp_policy.yaml`)."""

    dof: int = 7
    num_points: int = 1024  # M, the robot points
    channels: int = 4  # C of the 3D conv encoder
    env_hidden: list[int] = field(default_factory=lambda: [512, 256])  # MLP_II after the flattened (M x (C + 1)) point features
    point_hidden: list[int] = field(default_factory=lambda: [64, 128, 256])  # PointNet shared MLP; the last width is its feature size
    config_hidden: list[int] = field(default_factory=lambda: [128])  # MLP_I over [q_t, q_g]
    fusion_hidden: list[int] = field(default_factory=lambda: [512, 256, 128])  # MLP_III before the dof outputs
    point_encoder: bool = True  # ablation: False drops the PointNet branch
    env_encoder: bool = True  # ablation: False drops the environment branch (no grid at all)
    goal_features: bool = True  # MLP_I also sees u_g - u_t, its direction and its length (False: the paper's [u_t, u_g])
    norm: str = "group"  # Phi_3D's normalisation: group (per scene), batch (the paper's) or none; see `EnvEncoder`
    registration: str = "centres"  # where feature cells sit: centres (their true centres) or bounds (older checkpoints)


def goal_features(u_t: torch.Tensor, u_g: torch.Tensor, extra: bool) -> torch.Tensor:
    """MLP_I's input: (B, n) normalised current and goal -> (B, 2n) [u_t, u_g], or with `extra`
    (B, 4n + 1) [u_t, u_g, d, d / |d|, |d|] for d = u_g - u_t.

    The extra terms are functions of [u_t, u_g], so they add no information; they add the bias a
    goal-reaching policy needs. Without them an MLP trained on a few hundred demonstrations learns
    the direction to the goal only near the demonstrated paths, and its rollouts settle about 0.5 rad
    short of the goal; with them, about 0.04 rad (quickstart data, MLP_I alone, 1500 steps).
    """
    if not extra:
        return torch.cat([u_t, u_g], dim=-1)
    d = u_g - u_t
    dist = d.norm(dim=-1, keepdim=True)
    return torch.cat([u_t, u_g, d, d / dist.clamp(min=1e-3), dist], dim=-1)


def normalize(q: torch.Tensor, limits: torch.Tensor) -> torch.Tensor:
    """Radians -> [-1, 1] by the (n, 2) joint limits."""
    lo, hi = limits[:, 0], limits[:, 1]
    return 2 * (q - lo) / (hi - lo) - 1


def denormalize(u: torch.Tensor, limits: torch.Tensor) -> torch.Tensor:
    lo, hi = limits[:, 0], limits[:, 1]
    return lo + (u + 1) * (hi - lo) / 2


def sample_by_scene(volumes: torch.Tensor, scene_index: torch.Tensor, points: torch.Tensor, bounds) -> torch.Tensor:
    """Trilinear values of per-scene volumes at each sample's points, without copying a volume per sample.

    Args: volumes (S, C, n, n, n) indexed (x, y, z); scene_index (B,) into them; points (B, M, 3).
    Returns: (B, C, M).
    """
    B, M, _ = points.shape
    if len(volumes) == 1:  # one scene (a rollout of one problem): no grouping needed
        return sample_grid(volumes, points.reshape(1, B * M, 3), bounds).view(-1, B, M).transpose(0, 1)
    out = points.new_zeros(B, volumes.shape[1], M, dtype=volumes.dtype)
    for s in scene_index.unique().tolist():
        rows = (scene_index == s).nonzero()[:, 0]
        vals = sample_grid(volumes[s:s + 1], points[rows].reshape(1, -1, 3), bounds)  # (1, C, k * M)
        out = out.index_put((rows,), vals.reshape(-1, len(rows), M).transpose(0, 1))
    return out


def first_argmax(z: torch.Tensor, block: int = 32) -> torch.Tensor:
    """`z.argmax(dim=1)` for z (B, M, F) -> (B, F): the first index of each maximum, found by blocks.

    A CPU argmax costs about ten times an amax (15 ms against 1.3 ms for the quickstart PointNet's
    50 x 1024 x 128 at one thread), so the maxima of blocks of `block` points come from amax, the first
    block that holds the overall maximum from a comparison, and the first point within it likewise: the same
    indices as argmax, ties and NaN (a NaN is a maximum) included, for about a quarter of the time."""
    B, M, F = z.shape
    if M % block:
        return z.argmax(dim=1)
    blocks = z.view(B, M // block, block, F)
    first = _first_max(blocks.amax(dim=2))  # (B, F) the first block that holds the maximum
    inside = blocks.gather(1, first[:, None, None, :].expand(B, 1, block, F))[:, 0]  # (B, block, F)
    return first * block + _first_max(inside)


def _first_max(z: torch.Tensor) -> torch.Tensor:
    """(B, K, F) -> (B, F) the first k where z[:, k] is the maximum over k (as argmax; NaN counts as the max)."""
    K = z.shape[1]
    top = z.amax(dim=1, keepdim=True)  # NaN wherever a NaN is present, as argmax's pick
    hit = (z == top) | (z.isnan() & top.isnan())
    rank = torch.arange(K, 0, -1, device=z.device, dtype=torch.int32)[None, :, None]  # K for k = 0 ... 1 for K - 1
    return K - torch.where(hit, rank, 0).amax(dim=1).long()


def max_over_points(mlp: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """`mlp(x).amax(dim=1)` for x (B, M, D) -> (B, F), with gradients computed from the winning points only.

    A trailing ELU is applied after the max rather than to every point: ELU is increasing, so the max of
    ELU(z) is ELU(max z), with the same winner and gradient, for 1 row instead of M.

    A max over points passes gradient to one point per output feature, so at most F of the M points (F = 128
    of 1024 in the quickstart network) take part in the backward pass. With autograd on, the shared MLP runs
    once over all points without a graph to find the winners, then again with a graph over the F winning
    points (one per feature, so B x F rows): the values and the gradients are amax's (ties aside, which
    amax would split), at about half the cost of differentiating the MLP over every point. The pass without
    a graph goes a few samples at a time (`_by_chunks`), so each layer's output stays in cache.
    """
    layers = list(mlp)
    tail = layers.pop() if isinstance(layers[-1], nn.ELU) else nn.Identity()

    def trunk(h: torch.Tensor) -> torch.Tensor:
        for layer in layers:
            h = layer(h)
        return h

    if not torch.is_grad_enabled() or not (x.requires_grad or any(p.requires_grad for p in mlp.parameters())):
        return tail(_by_chunks(lambda c: _trunk_without_graph(layers, c).amax(dim=1), x))
    with torch.no_grad():  # (B, F) each feature's winning point
        winners = _by_chunks(lambda c: first_argmax(_trunk_without_graph(layers, c, search=True)), x)
    picked = x.gather(1, winners[..., None].expand(-1, -1, x.shape[-1]))  # (B, F, D)
    return tail(trunk(picked).diagonal(dim1=1, dim2=2))  # feature f of the point that won feature f


# Points per chunk of the pass over every point: a chunk's widest layer output (4096 x 128 floats, 2 MB)
# stays in a core's cache between the product, the ELU and the max, where the whole batch's (26 MB at
# 50 x 1024 points) goes out to memory and back; the pass takes about 20 % less time.
_CHUNK_POINTS = 4096


def _by_chunks(per_sample, x: torch.Tensor) -> torch.Tensor:
    """`per_sample(x)` for x (B, M, D), computed on chunks of whole samples of about `_CHUNK_POINTS` points
    (a result per sample, so the chunks' results are stacked as they are)."""
    chunks = x.split(max(1, _CHUNK_POINTS // max(1, x.shape[1])))
    return per_sample(x) if len(chunks) == 1 else torch.cat([per_sample(c) for c in chunks])


def _trunk_without_graph(layers: list[nn.Module], h: torch.Tensor, search: bool = False) -> torch.Tensor:
    """Linear and ELU layers over every point without autograd: the product, then the bias added and the ELU
    applied in place. A CPU `addmm` with a bias over 51 200 rows (50 x 1024 points) costs about twice the plain
    product plus the add, and the in-place ELU saves a tensor of that size per layer.

    `search`: the values only pick the winning points (`max_over_points`), so ELU's negative side is taken as
    exp(z) - 1 instead of expm1(z): at most 6e-8 away, at half the time of CPU ELU (whose expm1 is not
    vectorised), and a last Linear layer's bias, the same for every point, is left out. Two points within
    rounding of each other may then swap as the winner, which moves the maximum by as much; the winners'
    values themselves are computed again exactly."""
    own = False  # whether h is a tensor made here (never write into the caller's input)
    with torch.no_grad():
        for i, layer in enumerate(layers):
            if isinstance(layer, nn.Linear):
                h, own = torch.matmul(h, layer.weight.t()), True
                if layer.bias is not None and not (search and i == len(layers) - 1):  # a bias moves no maximum
                    h.add_(layer.bias)
            elif isinstance(layer, nn.ELU) and own and search and layer.alpha == 1.0:
                h = torch.maximum(h, h.clamp(max=0).exp_().sub_(1), out=h)
            elif isinstance(layer, nn.ELU) and own:
                h = torch.nn.functional.elu_(h, layer.alpha)
            else:
                h, own = layer(h), True
        return h


def _run_mlp(mlp: nn.Sequential, x: torch.Tensor) -> torch.Tensor:
    """`mlp(x)` for an `_mlp` of Linear and ELU layers, through the functional calls their modules make (the same
    numbers), without a module call per layer: at B = 1 those calls were a tenth of a policy step. Without
    autograd each ELU works in place on its Linear's fresh output."""
    in_place, own = not torch.is_grad_enabled(), False  # own: x is a tensor made here (never the caller's)
    for layer in mlp:
        if isinstance(layer, nn.Linear):
            x, own = F.linear(x, layer.weight, layer.bias), True
        elif isinstance(layer, nn.ELU):
            x = F.elu_(x, layer.alpha) if in_place and own else F.elu(x, layer.alpha)
        else:
            x, own = layer(x), False
    return x


def _mlp(sizes: list[int], last_activation: bool = True) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i, (a, b) in enumerate(zip(sizes[:-1], sizes[1:])):
        layers.append(nn.Linear(a, b))
        if last_activation or i < len(sizes) - 2:
            layers.append(nn.ELU())
    return nn.Sequential(*layers)


NORMS = ("batch", "group", "none")
REGISTRATIONS = ("centres", "bounds")


class EnvEncoder(nn.Module):
    """Phi_3D: Conv3d(1 -> C, k 3, stride 2, padding 1) + normalisation + ELU + MaxPool(2, stride 1).

    Where a feature sits: conv output j is centred on input cell 2j, and pooled feature k covers conv
    outputs k and k + 1, so it is centred on input cell 2k + 1. `feature_bounds` gives the box that the
    feature cells' centres span, so that a feature is read where it was computed ("centres"). Checkpoints
    trained before this read the volume as if it spanned the grid's own bounds ("bounds"), up to two input
    cells away from where each feature was computed; they keep that convention when loaded.

    Normalisation: "batch" is the paper's BatchNorm, whose training statistics come from the one or two
    scenes of a batch; "group" normalises each scene's volume on its own (GroupNorm, one group per channel),
    the same in training and evaluation; "none" keeps the conv's output as it is.
    """

    def __init__(self, channels: int, norm: str = "group", registration: str = "centres"):
        super().__init__()
        if norm not in NORMS:
            raise ValueError(f"model.norm must be one of {NORMS}, got {norm!r}")
        if registration not in REGISTRATIONS:
            raise ValueError(f"model.registration must be one of {REGISTRATIONS}, got {registration!r}")
        layer = {"batch": lambda: nn.BatchNorm3d(channels), "group": lambda: nn.GroupNorm(channels, channels),
                 "none": nn.Identity}[norm]()
        self.net = nn.Sequential(nn.Conv3d(1, channels, 3, stride=2, padding=1), layer, nn.ELU(),
                                 nn.MaxPool3d(2, stride=1))
        self.registration = registration

    def forward(self, grids: torch.Tensor) -> torch.Tensor:
        """(S, n, n, n) grids indexed (x, y, z) -> (S, C, n', n', n') feature volumes, same index order."""
        return self.net(grids[:, None])

    def feature_bounds(self, bounds, n_e: int, n_features: int):
        """The box that the feature cells' centres span, for grids of n_e anchors over `bounds`
        ((lo_x, lo_y, lo_z), (hi_x, hi_y, hi_z)), as the same kind of pair; `bounds` itself under the
        "bounds" registration."""
        if self.registration == "bounds":
            return bounds
        return _centres_box(tuple(map(tuple, bounds)), n_e, n_features)


@functools.lru_cache(maxsize=64)
def _centres_box(bounds: tuple, n_e: int, n_features: int) -> tuple[list[float], list[float]]:
    """Feature k sits on input anchor 2k + 1 (see `EnvEncoder`): the first on anchor 1, the last on 2n' - 1."""
    (lo, hi), cell = bounds, [(b - a) / (n_e - 1) for a, b in zip(*bounds)]
    return [a + c for a, c in zip(lo, cell)], [a + (2 * n_features - 1) * c for a, c in zip(lo, cell)]


class SAMPNet(nn.Module):
    """Predicts the next normalised configuration. Pure torch: no Lightning, no robot model inside."""

    def __init__(self, cfg: PolicyConfig):
        super().__init__()
        self.cfg = cfg
        M, C = cfg.num_points, cfg.channels
        width = 0
        if cfg.env_encoder:
            self.env = EnvEncoder(C, cfg.norm, cfg.registration)
            self.env_mlp = _mlp([M * (C + 1), *cfg.env_hidden])
            width += cfg.env_hidden[-1]
        if cfg.point_encoder:
            self.point_mlp = _mlp([4, *cfg.point_hidden])
            width += cfg.point_hidden[-1]
        self.config_mlp = _mlp([(4 * cfg.dof + 1) if cfg.goal_features else 2 * cfg.dof, *cfg.config_hidden])
        width += cfg.config_hidden[-1]
        self.fusion = _mlp([width, *cfg.fusion_hidden, cfg.dof], last_activation=False)

    def encode_scenes(self, grids: torch.Tensor) -> torch.Tensor | None:
        """(S, n, n, n) -> (S, C, n', n', n'); encode each distinct scene once and index per sample."""
        return self.env(grids) if self.cfg.env_encoder else None

    def forward(self, u_t: torch.Tensor, u_g: torch.Tensor, points: torch.Tensor, robot_sdf: torch.Tensor,
                features: torch.Tensor | None, scene_index: torch.Tensor | None, bounds, n_e: int | None = None
                ) -> torch.Tensor:
        """One step.

        Args:
            u_t, u_g: (B, n) current and goal configurations, normalised.
            points: (B, M, 3) robot points at u_t in the base frame (metres).
            robot_sdf: (B, M) robot SDF at those points (metres).
            features: (S, C, n', n', n') from `encode_scenes`; scene_index: (B,) into it.
            bounds: the workspace bounds the grids span; n_e: the grids' anchors per axis (needed to place the
                feature cells, see `EnvEncoder`).
        Returns:
            (B, n) the next configuration, normalised and clamped to [-1, 1].
        """
        B, M, _ = points.shape
        if M != self.cfg.num_points or u_t.shape[-1] != self.cfg.dof:
            raise ValueError(f"SAMPNet was built for {self.cfg.num_points} points and {self.cfg.dof} joints; got "
                             f"points {tuple(points.shape)} and q {tuple(u_t.shape)}")
        env_in = None
        if self.cfg.env_encoder:
            if n_e is None and self.env.registration == "centres":
                raise ValueError("SAMPNet.forward needs n_e (the grids' anchors per axis) to place the feature cells")
            box = self.env.feature_bounds(bounds, n_e, features.shape[-1])
            env = sample_by_scene(features, scene_index, points, box).transpose(1, 2)  # (B, M, C)
            env_in = torch.cat([env, robot_sdf[..., None]], dim=-1).reshape(B, -1)
        point_in = torch.cat([points, robot_sdf[..., None]], dim=-1) if self.cfg.point_encoder else None
        return self.head(u_t, goal_features(u_t, u_g, self.cfg.goal_features), env_in, point_in)

    def head(self, u_t: torch.Tensor, config_in: torch.Tensor, env_in: torch.Tensor | None,
             point_in: torch.Tensor | None) -> torch.Tensor:
        """The learned layers of a step, from their inputs: u_t (B, n); config_in (B, 2n or 4n + 1) from
        `goal_features`; env_in (B, M (C + 1)) each point's scene features and robot SDF, flattened; point_in
        (B, M, 4) the points and their robot SDF (either is ignored, and may be None, without its branch).
        -> (B, n) the next configuration, normalised and clamped."""
        parts = [_run_mlp(self.config_mlp, config_in)]
        if self.cfg.env_encoder:
            parts.append(_run_mlp(self.env_mlp, env_in))
        if self.cfg.point_encoder:
            parts.append(max_over_points(self.point_mlp, point_in))
        u = u_t + _run_mlp(self.fusion, torch.cat(parts[::-1], dim=-1))
        # Clamped to the limits in value; in the backward pass the clamp lets gradients through, so a
        # prediction beyond a limit is pulled back instead of stalling on a zero gradient.
        return u + (u.clamp(-1.0, 1.0) - u).detach()
