"""What the baseline systems share with each other and with the SAMP policy's: the robot, the dataset
check at fit time, AdamW with cosine warm restarts, the NaN guard, self-contained checkpoints, the
environment check before a rollout, and the evaluation after training (`eval/metrics.json`).

A baseline checkpoint carries a `baseline` record ({"kind": "mpinet" | "mpnet", robot, dataset, n_e,
bounds}); `samp.policy.load_policy` looks for it to hand the checkpoint to `planner_from_checkpoint`.
"""

from __future__ import annotations

from pathlib import Path

import pytorch_lightning as pl
import torch

from samp.policy.system import adamw_warm_restarts, bind_dataset, check_finite

__all__ = ["BaselineSystem", "check_env"]


def check_env(system, env) -> None:
    """Refuse an `EnvBatch` whose bounds or grid resolution differ from what `system` was trained on."""
    bounds = torch.as_tensor(system.hparams.bounds, dtype=env.bounds.dtype, device=env.bounds.device)
    if not torch.allclose(env.bounds, bounds.expand_as(env.bounds), atol=1e-9):
        raise ValueError(f"the {system.kind} policy was trained on workspace bounds {system.hparams.bounds}; these "
                         f"scenes have {env.bounds.tolist()}")
    n_e = system.hparams.n_e
    if env.grids is None or tuple(env.grids.shape[1:]) != (n_e,) * 3:
        raise ValueError(f"the {system.kind} policy reads grids at n_e = {n_e}; got "
                         f"{None if env.grids is None else tuple(env.grids.shape)}")


class BaselineSystem(pl.LightningModule):
    """Base of `MPiNetSystem` and `MPNetSystem`. A subclass sets `kind`, calls `super().__init__()`,
    `self.save_hyperparameters()` and `self._init_robot(robot)`, and implements `_losses(batch) -> dict`
    (with a "loss" entry) and `planner(**options)` (a `StepPolicy` or a `TrajectoryPlanner`)."""

    kind = "baseline"

    def _init_robot(self, robot: str) -> None:
        from samp.robot import load_robot

        self.robot = load_robot(robot)
        self.robot.requires_grad_(False)
        self.grids = None

    def to(self, *args, **kwargs):
        """Also moves the robot's kinematic chain (which `nn.Module.to` alone would not)."""
        super().to(*args, **kwargs)
        self.robot.to(*args, **kwargs)
        return self

    @property
    def limits(self) -> torch.Tensor:
        return self.robot.joint_limits.to(self.device, torch.float32)

    def fitted(self) -> None:
        if self.hparams.n_e is None:
            raise ValueError(f"this {self.kind} model was never fitted to a dataset (its n_e is unknown); train it first")

    # ------------------------------------------------------------------ Lightning hooks
    def on_fit_start(self) -> None:
        dm = self.trainer.datamodule
        bind_dataset(self, dm, f"{self.kind} model")
        self._fit_data(dm)

    def _fit_data(self, dm) -> None:
        """Per-dataset state a subclass needs during training (obstacle points, trajectories)."""

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        losses = self._losses(batch)
        check_finite(self, losses, self.kind)
        self.log_dict({f"train/{k}": v for k, v in losses.items()}, batch_size=len(batch["q"]))
        self.log("loss", losses["loss"], prog_bar=True, logger=False, batch_size=len(batch["q"]))
        return losses["loss"]

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        losses = self._losses(batch)
        self.log_dict({f"val/{k}": v for k, v in losses.items()}, batch_size=len(batch["q"]))

    def configure_optimizers(self):
        return adamw_warm_restarts(self, self.net.parameters())

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint["baseline"] = {"kind": self.kind, "robot": self.robot.name, "robot_asset_hash": self.robot.asset_hash,
                                  "n_e": self.hparams.n_e, "bounds": self.hparams.bounds,
                                  "dataset_id": self.hparams.dataset_id}

    # ------------------------------------------------------------------ after training
    def evaluate_run(self, run_dir: str | Path) -> dict:
        """Evaluate the trained baseline as `python -m samp.eval run=RUN_DIR` does for a SAMP run (same
        problems, checks and `eval/metrics.json` format, the expert and the straight line beside it)."""
        if not self.hparams.eval_problems:
            return {}
        from samp.eval.__main__ import evaluate_trained

        dm = self.trainer.datamodule if self._trainer is not None else None
        return evaluate_trained(run_dir, self.kind, self.hparams.eval_problems, dm.root if dm is not None else None)

    @classmethod
    def from_checkpoint(cls, checkpoint: str | Path | dict, map_location="cpu"):
        """Rebuild a trained baseline from its checkpoint (a path or the loaded dict) alone."""
        ckpt = checkpoint if isinstance(checkpoint, dict) else torch.load(checkpoint, map_location=map_location,
                                                                          weights_only=False)
        record = ckpt.get("baseline") or {}
        if record.get("kind") != cls.kind:
            raise ValueError(f"not a {cls.kind} checkpoint (its baseline record says {record.get('kind')!r})")
        system = cls(**ckpt["hyper_parameters"])
        if system.robot.asset_hash != record["robot_asset_hash"]:
            raise ValueError(f"the checkpoint was trained on robot assets {record['robot_asset_hash'][:12]}, but "
                             f"{system.robot.name!r} now loads {system.robot.asset_hash[:12]} (different URDF or meshes)")
        system.load_state_dict(ckpt["state_dict"])
        return system.eval()
