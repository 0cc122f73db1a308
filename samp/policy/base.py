"""`PolicySystemBase`: what every trainable planner's LightningModule shares (SAMP, MPiNet, MPNet).

A subclass names its `kind` (`class MySystem(PolicySystemBase, kind="mine")`, which also registers it
for `samp.policy.load_policy`), builds its network in `__init__` after `super().__init__(robot, optimizer,
scheduler)` and `self.save_hyperparameters()`, and implements:

  _losses(batch) -> dict     the loss terms, with the total under "loss" (each is logged as train/<k>, val/<k>)
  planner(**options)          the current weights as a `StepPolicy` or a `TrajectoryPlanner` (samp.policy.interface)
  _bound(binding)             (optional) per-dataset state to derive once the dataset is bound

The base owns the robot (moved with `.to`), the joint limits, the dataset binding (`bind`, at fit start:
the grids as a non-persistent buffer, everything else saved in the checkpoint), the training and
validation steps with the NaN stop, the optimizer and scheduler from config, and the checkpoint record
`checkpoint["samp"] = {"kind", "robot", "robot_asset_hash", "binding", ...}` that `from_checkpoint` reads.
It neither evaluates itself nor builds what it needs: the training recipe (`samp.train`) does.
"""

from __future__ import annotations

from pathlib import Path

import pytorch_lightning as pl
import torch

from samp.data.binding import DatasetBinding
from samp.names import BATCH_Q, CHECKPOINT_RECORD, TRAIN_PREFIX, VAL_PREFIX
from samp.policy.registry import register_policy

__all__ = ["DEFAULT_OPTIMIZER", "DEFAULT_SCHEDULER", "NonFiniteLossError", "PolicySystemBase"]

# The paper's recipe (AdamW with cosine warm restarts), as config nodes: conf/optimizer/ holds the same.
# fused: one kernel per step instead of a pass per operation, 3.6 ms instead of 17 ms for the quickstart
# network's 3.2 M parameters on one CPU thread; its updates equal the default's up to rounding (5e-10 after 3 steps).
DEFAULT_OPTIMIZER = {"_target_": "torch.optim.AdamW", "_partial_": True, "lr": 1e-4, "weight_decay": 1e-2,
                     "fused": True}
DEFAULT_SCHEDULER = {"_target_": "torch.optim.lr_scheduler.CosineAnnealingWarmRestarts", "_partial_": True,
                     "T_0": 10, "T_mult": 2}


class NonFiniteLossError(FloatingPointError):
    """Training produced a NaN or infinite loss (`samp.train` exits 1 with this message)."""


OPTIMIZER_MODULE = "torch.optim."  # optimizers and (torch.optim.lr_scheduler) schedulers


def _partial(node: dict | None, what: str):
    """A `_partial_` config node (plain dict) -> the callable it describes. The node travels inside every
    checkpoint (its hyperparameters), so it may name nothing but a torch optimizer or scheduler, with plain
    values: a nested `_target_` would be called while the checkpoint loads (docs/design.md section 7)."""
    from hydra.utils import instantiate

    if not isinstance(node, dict) or "_target_" not in node:
        raise ValueError(f"{what} must be a config node with a _target_ (conf/optimizer/), got {node!r}")
    target = node["_target_"]
    if not isinstance(target, str) or not target.startswith(OPTIMIZER_MODULE):
        raise ValueError(f"{what}: _target_ {target!r} is not a torch optimizer or scheduler ({OPTIMIZER_MODULE}*); "
                         "a checkpoint names no other code (conf/optimizer/ shows the form)")
    nested = _targets(node, top=True)
    if nested:
        raise ValueError(f"{what}: its values may not name code to call ({', '.join(map(repr, nested))}); "
                         "give numbers, strings, booleans and lists of them")
    return instantiate({**node, "_partial_": True})


def _targets(value, top: bool = False) -> list:
    """Every `_target_` inside `value` (a config node), its own top-level one left out when `top`."""
    if isinstance(value, dict):
        found = [] if top else [value["_target_"]] if "_target_" in value else []
        return found + [t for k, v in value.items() if k != "_target_" or not top for t in _targets(v)]
    if isinstance(value, (list, tuple)):
        return [t for v in value for t in _targets(v)]
    return []


class PolicySystemBase(pl.LightningModule):
    """Args (every subclass takes these three):
        robot: robot name (conf/robot/).
        optimizer: a `_partial_` config node for the optimizer (default AdamW, lr 1e-4, weight decay 1e-2).
        scheduler: a `_partial_` config node for an epoch-wise LR scheduler, or None for none (default
            cosine annealing with warm restarts, T_0 10, T_mult 2).
    """

    kind = "policy"

    def __init_subclass__(cls, kind: str | None = None, **kwargs):
        super().__init_subclass__(**kwargs)
        if kind is not None:
            cls.kind = kind
            register_policy(kind, cls)

    def __init__(self, robot: str = "panda", optimizer: dict | None = None, scheduler: dict | None = None):
        super().__init__()
        from samp.robot import load_robot

        self.robot = load_robot(robot)
        self.robot.requires_grad_(False)
        self.optimizer_cfg = dict(optimizer or DEFAULT_OPTIMIZER)
        self.scheduler_cfg = DEFAULT_SCHEDULER if scheduler is None else scheduler  # {} or False: no scheduler
        _partial(self.optimizer_cfg, "optimizer")  # a bad optimizer node fails before training, not after
        self.binding: DatasetBinding | None = None
        self.register_buffer("grids", None, persistent=False)  # (S, n_e, n_e, n_e) while bound to a dataset

    # ------------------------------------------------------------------ robot and dataset
    def to(self, *args, **kwargs):
        """Also moves the robot's kinematic chain (which `nn.Module.to` alone would not)."""
        super().to(*args, **kwargs)
        self.robot.to(*args, **kwargs)
        return self

    @property
    def limits(self) -> torch.Tensor:
        """(n, 2) joint limits, radians, float32 on the system's device (converted once per device)."""
        cached = self.__dict__.get("_limits32")
        if cached is None or cached.device != self.device:
            cached = self.__dict__["_limits32"] = self.robot.joint_limits.to(self.device, torch.float32)
        return cached

    @property
    def n_e(self) -> int | None:
        return None if self.binding is None else self.binding.n_e

    @property
    def bounds(self) -> tuple | None:
        return None if self.binding is None else self.binding.bounds

    @property
    def dataset_id(self) -> str | None:
        return None if self.binding is None else self.binding.dataset_id

    def fitted(self) -> None:
        """ValueError unless the system has been bound to a dataset (trained, or loaded from a checkpoint)."""
        if self.binding is None:
            raise ValueError(f"this {self.kind} model was never fitted to a dataset (its n_e and bounds are "
                             "unknown); train it first")

    def bind(self, binding: DatasetBinding) -> None:
        """Take a dataset's binding: refuse another robot, hold the grids (not saved), keep the rest."""
        if binding.robot != self.robot.name or binding.robot_asset_hash != self.robot.asset_hash:
            raise ValueError(f"dataset {binding.dataset_id} is for robot {binding.robot!r} (assets "
                             f"{binding.robot_asset_hash[:12]}); the {self.kind} model is for {self.robot.name!r} "
                             f"(assets {self.robot.asset_hash[:12]}): use a dataset generated for this robot")
        if self.binding is not None and (self.binding.n_e, self.binding.bounds) != (binding.n_e, binding.bounds):
            raise ValueError(f"the {self.kind} model was trained at n_e = {self.binding.n_e} with bounds "
                             f"{self.binding.bounds}; dataset {binding.dataset_id} gives n_e = {binding.n_e}, bounds "
                             f"{binding.bounds}")
        self.binding = binding.without_grids()
        self.grids = None if binding.grids is None else binding.grids.to(self.device)
        self._bound(binding)

    def _bound(self, binding: DatasetBinding) -> None:
        """Per-dataset state a subclass derives once (obstacle points, ...); `self.grids` is set."""

    def check_env(self, env) -> None:
        """Refuse an `EnvBatch` whose bounds or grid resolution differ from what the system was trained on."""
        self.fitted()
        bounds = torch.as_tensor(self.bounds, dtype=env.bounds.dtype, device=env.bounds.device)
        if not torch.allclose(env.bounds, bounds.expand_as(env.bounds), atol=1e-9):
            raise ValueError(f"the {self.kind} policy was trained on workspace bounds {self.bounds}; these scenes have "
                             f"{env.bounds.tolist()}")
        if env.grids is None or tuple(env.grids.shape[1:]) != (self.n_e,) * 3:
            raise ValueError(f"the {self.kind} policy reads grids at n_e = {self.n_e}; got "
                             f"{None if env.grids is None else tuple(env.grids.shape)}")

    # ------------------------------------------------------------------ what a subclass provides
    def _losses(self, batch: dict) -> dict[str, torch.Tensor]:
        raise NotImplementedError

    def planner(self, **options):
        """The current weights as a `StepPolicy` or a `TrajectoryPlanner`, for rollouts."""
        raise NotImplementedError

    def _checkpoint_extra(self) -> dict:
        """More of the checkpoint record (what `from_checkpoint` needs besides the hyperparameters)."""
        return {}

    # ------------------------------------------------------------------ Lightning hooks
    def on_fit_start(self) -> None:
        self.bind(self.trainer.datamodule.binding)

    def _check_finite(self, losses: dict[str, torch.Tensor]) -> None:
        if torch.isfinite(losses["loss"]):
            return
        parts = ", ".join(f"{k} {v.item():.4g}" for k, v in losses.items() if k != "loss")
        raise NonFiniteLossError(
            f"{self.kind} training loss is {losses['loss'].item()} at epoch {self.current_epoch}, step "
            f"{self.global_step} ({parts}); the last good checkpoint is kept in the run's checkpoints/. "
            "Lower the learning rate or check the dataset (`python -m samp.data verify`)")

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        losses = self._losses(batch)
        self._check_finite(losses)
        size = len(batch[BATCH_Q])
        # data-parallel: every rank holds a part of the global batch, so the logged loss is the mean of the parts
        sync = self.trainer.world_size > 1
        self.log_dict({f"{TRAIN_PREFIX}{k}": v for k, v in losses.items()}, batch_size=size, sync_dist=sync)
        self.log("loss", losses["loss"], prog_bar=True, logger=False, batch_size=size, sync_dist=sync)
        return losses["loss"]

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        losses = self._losses(batch)  # every rank validates on the whole set: the same values everywhere
        self.log_dict({f"{VAL_PREFIX}{k}": v for k, v in losses.items()}, batch_size=len(batch[BATCH_Q]),
                      sync_dist=self.trainer.world_size > 1)

    def trainable_parameters(self):
        return self.net.parameters()

    def configure_optimizers(self):
        opt = _partial(self.optimizer_cfg, "optimizer")(self.trainable_parameters())
        if not self.scheduler_cfg:
            return opt
        sched = _partial(self.scheduler_cfg, "scheduler")(opt)
        return {"optimizer": opt, "lr_scheduler": {"scheduler": sched, "interval": "epoch"}}

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        checkpoint[CHECKPOINT_RECORD] = {"kind": self.kind, "robot": self.robot.name,
                                         "robot_asset_hash": self.robot.asset_hash,
                                         "binding": None if self.binding is None else self.binding.meta(),
                                         **self._checkpoint_extra()}

    def on_load_checkpoint(self, checkpoint: dict) -> None:
        """Resuming a fit: the binding saved with the weights (the DataModule's replaces it at fit start)."""
        meta = (checkpoint.get(CHECKPOINT_RECORD) or {}).get("binding")
        if meta:
            self.binding = DatasetBinding.from_meta(meta)

    # ------------------------------------------------------------------ loading
    @classmethod
    def _build(cls, hparams: dict, record: dict):
        """The system for a checkpoint's hyperparameters and record (a subclass may add to it)."""
        return cls(**hparams)

    @classmethod
    def from_checkpoint(cls, checkpoint: str | Path | dict, map_location="cpu"):
        """Rebuild a trained system from its checkpoint (a path or the loaded dict) alone, in eval mode."""
        from samp.policy.registry import read_checkpoint

        ckpt = read_checkpoint(checkpoint, map_location)
        record = ckpt[CHECKPOINT_RECORD]
        if record["kind"] != cls.kind:
            raise ValueError(f"not a {cls.kind} checkpoint: it holds a {record['kind']!r} model")
        system = cls._build(dict(ckpt["hyper_parameters"]), record)
        if system.robot.asset_hash != record["robot_asset_hash"]:
            raise ValueError(f"the checkpoint was trained on robot assets {record['robot_asset_hash'][:12]}, but "
                             f"{system.robot.name!r} now loads {system.robot.asset_hash[:12]} (different URDF or meshes)")
        system.load_state_dict(_without_stale_robot_buffers(ckpt["state_dict"], system))
        if record.get("binding"):
            system.binding = DatasetBinding.from_meta(record["binding"])
        return system.eval()


def _without_stale_robot_buffers(state: dict, system) -> dict:
    """A checkpoint's state without the robot-model buffers this version no longer keeps (derived index
    buffers that older versions saved, e.g. `robot._point_frames`); everything else must still match."""
    own = system.state_dict()
    robot_modules = tuple(f"{name}." for name, module in system.named_modules(remove_duplicate=False)
                          if name and type(module).__name__ == "Robot")
    return {k: v for k, v in state.items() if k in own or not k.startswith(robot_modules)}
