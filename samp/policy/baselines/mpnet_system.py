"""The MPNet-style planner's LightningModule: trains the obstacle encoder and the dropout planning network
on the same (q_t, q_{t+1}, q_goal, scene) samples as SAMP, with MPNet's loss, the mean squared error of
the predicted next configuration (normalised joint space, summed over joints).

MPNet grows its path from both ends toward each other, so the network must also step backwards along a
demonstration: a `reverse_fraction` of each training batch is flipped (current = q_{t+1} with the same
noise, next = q_t, goal = the trajectory's first waypoint), from the batch's noise-free q_t and q_0.
"""

from __future__ import annotations

import torch

from samp.names import BATCH_GOAL, BATCH_NEXT, BATCH_Q, BATCH_SCENE, BATCH_START, BATCH_STEP_CLEAN
from samp.policy.base import DEFAULT_OPTIMIZER, PolicySystemBase
from samp.policy.baselines.mpnet import MPNetConfig, MPNetNet
from samp.policy.network import normalize

__all__ = ["MPNetSystem", "next_config_loss"]


def next_config_loss(u_pred: torch.Tensor, u_true: torch.Tensor) -> torch.Tensor:
    """(B, n) normalised configurations -> scalar: squared error summed over joints, mean over the batch."""
    return (u_pred - u_true).square().sum(dim=-1).mean()


class MPNetSystem(PolicySystemBase, kind="mpnet"):
    """Args:
        robot: robot name. model: MPNetConfig fields (dof comes from the robot).
        reverse_fraction: share of each training batch stepped backwards along its trajectory.
        planning: MPNetPlanConfig fields, the planner's defaults (`samp.policy.baselines.mpnet_planner`).
        optimizer, scheduler: `_partial_` config nodes (conf/optimizer/; MPNet's default lr is 1e-3).
    """

    def __init__(self, robot: str = "panda", model: dict | None = None, reverse_fraction: float = 0.5,
                 planning: dict | None = None, optimizer: dict | None = None, scheduler: dict | None = None):
        if not 0.0 <= reverse_fraction <= 1.0:
            raise ValueError(f"reverse_fraction must be in [0, 1], got {reverse_fraction}")
        super().__init__(robot, optimizer or {**DEFAULT_OPTIMIZER, "lr": 1e-3}, scheduler)
        from samp.policy.baselines.mpnet_planner import MPNetPlanConfig

        self.save_hyperparameters()
        self.net_cfg = MPNetConfig(**{**(model or {}), "dof": self.robot.dof})
        self.net = MPNetNet(self.net_cfg)
        MPNetPlanConfig(**(planning or {}))  # a bad planner setting fails before training, not after

    def _reverse(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(q, q_next, q_goal) with a random `reverse_fraction` of the rows stepped backwards: from
        q_{t+1} plus the same noise toward q_t, with the trajectory's start as the goal."""
        q, q_next, goal = batch[BATCH_Q], batch[BATCH_NEXT], batch[BATCH_GOAL]
        if not self.training or self.hparams.reverse_fraction == 0:
            return q, q_next, goal
        here, start = batch[BATCH_STEP_CLEAN], batch[BATCH_START]  # q_t without noise, q_0
        flip = (torch.rand(len(q), device=q.device) < self.hparams.reverse_fraction)[:, None]
        lim = self.limits
        back = torch.minimum(torch.maximum(q_next + (q - here), lim[:, 0]), lim[:, 1])  # same noise, clamped
        return torch.where(flip, back, q), torch.where(flip, here, q_next), torch.where(flip, start, goal)

    def _losses(self, batch: dict) -> dict[str, torch.Tensor]:
        q, q_next, goal = self._reverse(batch)
        present, local = batch[BATCH_SCENE].unique(return_inverse=True)  # each distinct scene encoded once
        code = self.net.encode(self.grids[present])[local]  # (B, L)
        u_hat = self.net(code, normalize(q, self.limits), normalize(goal, self.limits))
        mse = next_config_loss(u_hat, normalize(q_next, self.limits))
        return {"mse": mse, "loss": mse}

    def planner(self, **options):
        """The trained network as a `TrajectoryPlanner` (samp.policy.interface); options override the planning defaults."""
        from samp.policy.baselines.mpnet_planner import MPNetPlanConfig, MPNetPlanner

        return MPNetPlanner(self, MPNetPlanConfig(**{**(self.hparams.planning or {}), **options}))
