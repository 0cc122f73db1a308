"""The MPNet-style planner's LightningModule: trains the obstacle encoder and the dropout planning network
on the same (q_t, q_{t+1}, q_goal, scene) samples as SAMP, with MPNet's loss, the mean squared error of
the predicted next configuration (normalised joint space, summed over joints).

MPNet grows its path from both ends toward each other, so the network must also step backwards along a
demonstration: a `reverse_fraction` of each training batch is flipped (current = q_{t+1} with the same
noise, next = q_t, goal = the trajectory's first waypoint), read from the DataModule's trajectories.
"""

from __future__ import annotations

import torch

from samp.policy.baselines.common import BaselineSystem
from samp.policy.baselines.mpnet import MPNetConfig, MPNetNet
from samp.policy.network import normalize

__all__ = ["MPNetSystem", "next_config_loss"]


def next_config_loss(u_pred: torch.Tensor, u_true: torch.Tensor) -> torch.Tensor:
    """(B, n) normalised configurations -> scalar: squared error summed over joints, mean over the batch."""
    return (u_pred - u_true).square().sum(dim=-1).mean()


class MPNetSystem(BaselineSystem):
    """Args:
        robot: robot name. model: MPNetConfig fields (dof comes from the robot).
        reverse_fraction: share of each training batch stepped backwards along its trajectory.
        planning: MPNetPlanConfig fields, the planner's defaults (`samp.policy.baselines.mpnet_planner`).
        lr, weight_decay, restart_epochs, restart_mult: AdamW with cosine warm restarts.
        eval_problems: problems per split for the evaluation after training (0: none).
        n_e, bounds, dataset_id: filled in from the DataModule at fit time and saved with the weights.
    """

    kind = "mpnet"

    def __init__(self, robot: str = "panda", model: dict | None = None, reverse_fraction: float = 0.5,
                 planning: dict | None = None, lr: float = 1e-3, weight_decay: float = 1e-2, restart_epochs: int = 10,
                 restart_mult: int = 2, eval_problems: int = 50, n_e: int | None = None, bounds=None,
                 dataset_id: str | None = None):
        super().__init__()
        if not 0.0 <= reverse_fraction <= 1.0:
            raise ValueError(f"reverse_fraction must be in [0, 1], got {reverse_fraction}")
        from samp.policy.baselines.mpnet_planner import MPNetPlanConfig

        self.save_hyperparameters()
        self._init_robot(robot)
        self.net_cfg = MPNetConfig(**{**(model or {}), "dof": self.robot.dof})
        self.net = MPNetNet(self.net_cfg)
        MPNetPlanConfig(**(planning or {}))  # a bad planner setting fails before training, not after
        self.trajectories = None

    def _fit_data(self, dm) -> None:
        self.trajectories = dm.trajectories.to(self.device)  # (N, W, n) radians

    def _reverse(self, batch: dict) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(q, q_next, q_goal) with a random `reverse_fraction` of the rows stepped backwards."""
        q, q_next, goal = batch["q"], batch["q_next"], batch["q_goal"]
        if not self.training or self.hparams.reverse_fraction == 0 or self.trajectories is None:
            return q, q_next, goal
        k, t = batch["traj"].to(self.device), batch["step"].to(self.device)
        here, ahead = self.trajectories[k, t], self.trajectories[k, t + 1]
        flip = (torch.rand(len(q), device=q.device) < self.hparams.reverse_fraction)[:, None]
        lim = self.limits
        back = torch.minimum(torch.maximum(ahead + (q - here), lim[:, 0]), lim[:, 1])  # same noise, clamped
        return (torch.where(flip, back, q), torch.where(flip, here, q_next),
                torch.where(flip, self.trajectories[k, 0], goal))

    def _losses(self, batch: dict) -> dict[str, torch.Tensor]:
        q, q_next, goal = self._reverse(batch)
        present, local = batch["scene"].unique(return_inverse=True)  # each distinct scene encoded once
        code = self.net.encode(self.grids[present])[local]  # (B, L)
        u_hat = self.net(code, normalize(q, self.limits), normalize(goal, self.limits))
        mse = next_config_loss(u_hat, normalize(q_next, self.limits))
        return {"mse": mse, "loss": mse}

    def planner(self, **options):
        """The trained network as a `samp.eval.TrajectoryPlanner`; options override the planning defaults."""
        from samp.policy.baselines.mpnet_planner import MPNetPlanConfig, MPNetPlanner

        return MPNetPlanner(self, MPNetPlanConfig(**{**(self.hparams.planning or {}), **options}))
