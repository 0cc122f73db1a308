"""The policy's training losses, exactly as docs/design.md section 4 ("Losses") defines them.

    L_match  = mean |T_q^(P) - T_q(P)| + mean (T_q^(P) - T_q(P))^2        (points in metres)
    L_coll   = (1/M) sum_i w_i max(0, m_i - C_i),   w_i = exp(-(d_i - d_target) / tau)
    L_config = || q^_{t+1} - q_{t+1} ||^2                                   (radians, summed over joints)
    L        = lambda_1 L_match + lambda_2 L_coll + lambda_3 L_config

C_i is the environment SDF at the i-th posed point of the prediction, trilinear from the anchor grid; the
margin m_i is d_margin (the definition of docs/design.md, `margin="fixed"`) or, with `margin="demo"`,
min(d_margin, C*_i) for C*_i the environment SDF at the same point of the demonstrated next configuration: a
prediction is asked to keep as clear as the expert did, up to d_margin, so that a demonstration that must come
close to an obstacle (a goal inside a cabinet) is not pushed away from where it ends;
d_i is the robot SDF at the same point, computed from the predicted joint angles in radians, and each
point gets its own weight (the authors' code multiplied mean weight by mean hinge instead, and fed the
robot SDF normalised angles; both are fixed here). The weights are treated as constants: they say how
much a point matters, and differentiating the robot SDF network through them would only add cost.

`LOSS_TERMS` is the one list of terms: a term names what it is logged as, the `LossConfig` field that
weights it, and how it is computed from a `StepPrediction`. Adding a term is one entry there and its
weight field in `LossConfig` (with a default of 0.0 it changes nothing until a config turns it on).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import torch

from samp.policy.network import sample_by_scene

__all__ = ["LOSS_TERMS", "LossConfig", "LossTerm", "StepPrediction", "collision_loss", "config_loss", "loss_terms",
           "match_loss"]


@dataclass
class LossConfig:
    match: float = 1.0  # lambda_1
    collision: float = 20.0  # lambda_2
    config: float = 1.0  # lambda_3
    d_margin: float = 0.09  # metres
    d_target: float = 0.015  # metres
    tau: float = 1.0  # temperature of the per-point weights (1: the paper's)
    margin: str = "fixed"  # fixed: d_margin everywhere (the paper's) | demo: min(d_margin, the demo's clearance)

    def __post_init__(self):
        if self.margin not in MARGINS:
            raise ValueError(f"loss.margin must be one of {MARGINS}, got {self.margin!r}")


MARGINS = ("fixed", "demo")


def match_loss(pred_points: torch.Tensor, true_points: torch.Tensor) -> torch.Tensor:
    """(B, M, 3) both -> scalar: mean absolute plus mean squared coordinate difference."""
    diff = pred_points - true_points
    return diff.abs().mean() + diff.square().mean()


def collision_loss(pred_points: torch.Tensor, grids: torch.Tensor, scene_index: torch.Tensor, bounds,
                   robot_sdf: torch.Tensor | Callable[[torch.Tensor], torch.Tensor], cfg: LossConfig,
                   true_points: torch.Tensor | None = None) -> torch.Tensor:
    """pred_points (B, M, 3); grids (S, n, n, n) the scenes' anchor grids and scene_index (B,) into them;
    robot_sdf (B, M) metres, or a function of the (B, M) mask of points where the hinge is active that gives
    them (the others may hold any finite value: their term is zero); true_points (B, M, 3) the demonstrated
    next configuration's points, read with `cfg.margin == "demo"` -> scalar.

    The hinge is zero wherever a point is farther than d_margin from every obstacle, and on demonstrations
    that keep clear of obstacles that is most points (about 99 % on the quickstart data), so asking for the
    robot SDF only where it is active is exact and saves most of a query. For the same reason the
    environment SDF is differentiated at the active points only: it is read everywhere without a graph, then
    again with one where the hinge acts (the same trilinear values, point by point), which spares the
    backward pass of the grid sampling at every other point."""
    margin = cfg.d_margin
    if cfg.margin == "demo":
        if true_points is None:
            raise ValueError('loss.margin="demo" needs the demonstrated points (true_points)')
        with torch.no_grad():
            demo = sample_by_scene(grids[:, None], scene_index, true_points, bounds)[:, 0]  # (B, M)
        margin = demo.clamp(max=cfg.d_margin)
    with torch.no_grad():
        env = sample_by_scene(grids[:, None], scene_index, pred_points, bounds)[:, 0]  # (B, M)
    hinge = torch.relu(margin - env)
    if torch.is_grad_enabled() and pred_points.requires_grad:
        b, m = torch.nonzero(~(hinge <= 0), as_tuple=True)  # (R,) each: the active points (and NaN ones)
        active = sample_by_scene(grids[:, None], scene_index[b], pred_points[b, m][:, None], bounds)[:, 0, 0]
        margin_active = margin[b, m] if isinstance(margin, torch.Tensor) else margin
        hinge = torch.zeros_like(hinge).index_put((b, m), torch.relu(margin_active - active))
    if callable(robot_sdf):
        robot_sdf = robot_sdf(hinge.detach() > 0)
    weights = torch.exp(-(robot_sdf.detach() - cfg.d_target) / cfg.tau)
    return (weights * hinge).mean()


def config_loss(q_pred: torch.Tensor, q_true: torch.Tensor) -> torch.Tensor:
    """(B, n) radians -> scalar: squared Euclidean distance, averaged over the batch."""
    return (q_pred - q_true).square().sum(dim=-1).mean()


@dataclass
class StepPrediction:
    """What the loss terms of one training step read.

    Attributes:
        q_hat, q_next: (B, n) predicted and demonstrated next configurations, radians.
        pred_points, true_points: (B, M, 3) the robot points posed at q_hat (with gradients) and at q_next.
        grids: (S, n_e, n_e, n_e) anchor grids; scene: (B,) index into them; bounds: the grids' bounds.
        robot_sdf: (needed (B, M) bool) -> (B, M) the robot SDF at `pred_points`, metres, exact where
            `needed` (elsewhere any finite value), computed on first use.
    """

    q_hat: torch.Tensor
    q_next: torch.Tensor
    pred_points: torch.Tensor
    true_points: torch.Tensor
    grids: torch.Tensor
    scene: torch.Tensor
    bounds: object
    robot_sdf: Callable[[torch.Tensor], torch.Tensor]
    _cache: dict = field(default_factory=dict, repr=False)

    def robot_sdf_at_prediction(self, needed: torch.Tensor) -> torch.Tensor:
        """The robot SDF at `pred_points`, exact where `needed` (B, M) is true; queried once per step."""
        if "robot_sdf" not in self._cache:
            self._cache["robot_sdf"] = self.robot_sdf(needed)
        return self._cache["robot_sdf"]


@dataclass(frozen=True)
class LossTerm:
    """One term of L: logged as `train/<name>`, weighted by `LossConfig.<weight>`."""

    name: str
    weight: str
    compute: Callable[[StepPrediction, LossConfig], torch.Tensor]


LOSS_TERMS = (
    LossTerm("match", "match", lambda s, c: match_loss(s.pred_points, s.true_points)),
    LossTerm("coll", "collision", lambda s, c: collision_loss(s.pred_points, s.grids, s.scene, s.bounds,
                                                              s.robot_sdf_at_prediction, c, s.true_points)),
    LossTerm("config", "config", lambda s, c: config_loss(s.q_hat, s.q_next)),
)


def loss_terms(step: StepPrediction, cfg: LossConfig, off: tuple[str, ...] = ()) -> dict[str, torch.Tensor]:
    """Every term of `LOSS_TERMS` (zero for the names in `off`, an ablation) and their weighted sum as
    "loss"."""
    unknown = set(off) - {t.name for t in LOSS_TERMS}
    if unknown:
        raise ValueError(f"unknown loss term(s) {sorted(unknown)}; the terms are {[t.name for t in LOSS_TERMS]}")
    zero = torch.zeros((), device=step.q_hat.device)
    out = {t.name: zero if t.name in off else t.compute(step, cfg) for t in LOSS_TERMS}
    out["loss"] = sum(getattr(cfg, t.weight) * out[t.name] for t in LOSS_TERMS)
    return out
