"""Training a robot SDF with Lightning: `RobotSDFDataModule` (samples -> random per-link batches) and
`RobotSDFSystem` (loss, metrics, optimiser, learning-rate decay, checkpoint description). The training
recipe exports the trained network and evaluates it (`samp.train.after_fit.export_robot_sdf`).

A step draws `near_per_step` near-surface and `uniform_per_step` uniform samples from every link (the
authors' 2048 + 1024) and regresses the network's normalised distance on the exact one (MSE, as in the
paper). The learning rate decays exponentially to `lr_final_factor` of its start over training, where
"training" ends at `trainer.max_steps` or after `time_limit_s` seconds, whichever comes first, so a
run cut short by the time limit still ends on a small learning rate.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from types import SimpleNamespace
from typing import Callable

import pytorch_lightning as pl
import torch
from torch import nn

from samp.robot_sdf.samples import SampleConfig, ensure_samples, load_samples

__all__ = ["BATCH_KEYS", "RobotSDFDataModule", "RobotSDFSystem"]

BATCH_KEYS = ("points", "sdf", "link")  # (P, 3) normalised points, (P,) normalised distance, (P,) link index
LOSSES = ("mse", "l1")


class _RandomBatches(torch.utils.data.Dataset):
    """`length` batches, each `near` + `uniform` random rows of every link (drawn with replacement)."""

    def __init__(self, samples, near_rows: list[torch.Tensor], uniform_rows: list[torch.Tensor], near: int,
                 uniform: int, length: int, seed: int, record=None):
        self.samples, self.near_rows, self.uniform_rows = samples, near_rows, uniform_rows
        self.near, self.uniform, self.length, self.record = near, uniform, length, record
        self.gen = torch.Generator().manual_seed(seed)

    def __len__(self) -> int:
        return self.length

    def __getitem__(self, index: int) -> dict[str, torch.Tensor]:
        picks = []
        for rows, count in [(r, self.near) for r in self.near_rows] + [(r, self.uniform) for r in self.uniform_rows]:
            if len(rows) and count:
                picks.append(rows[torch.randint(len(rows), (count,), generator=self.gen)])
        rows = torch.cat(picks)
        if self.record is not None:
            import hashlib

            from samp.data.module import _append_json

            _append_json(self.record, {"index": int(index), "rows": len(rows),
                                       "sha256": hashlib.sha256(rows.numpy().tobytes()).hexdigest()})
        s = self.samples
        return {"points": s.points[rows], "sdf": s.sdf[rows], "link": s.link[rows]}


class RobotSDFDataModule(pl.LightningDataModule):
    """The robot's SDF samples (generated once per config, then reused from the registry), split into
    training rows and a fixed validation subset (`val_fraction` of every link's rows)."""

    def __init__(self, robot: str, samples: dict | SampleConfig, near_per_step: int = 2048, uniform_per_step: int = 1024,
                 steps_per_epoch: int = 250, val_fraction: float = 0.02, val_batch: int = 65536, seed: int = 0,
                 root: str | None = None, record_draws: bool = False):
        super().__init__()
        if not 0 < val_fraction < 1:
            raise ValueError(f"val_fraction must be in (0, 1), got {val_fraction}")
        if near_per_step < 0 or uniform_per_step < 0 or near_per_step + uniform_per_step == 0 or steps_per_epoch < 1:
            raise ValueError("near_per_step and uniform_per_step must be >= 0 and not both 0, steps_per_epoch >= 1; got "
                             f"{near_per_step}, {uniform_per_step}, {steps_per_epoch}")
        from samp.robot_sdf.artifact import _plain

        self.robot_name = robot
        self.sample_config = samples if isinstance(samples, SampleConfig) else SampleConfig(**_plain(samples))
        self.near_per_step, self.uniform_per_step = near_per_step, uniform_per_step
        self.steps_per_epoch, self.val_fraction, self.val_batch, self.seed = steps_per_epoch, val_fraction, val_batch, seed
        self.root = Path(root) if root else None
        self.record_draws = bool(record_draws)  # a line per training batch in <run>/draws/rank<r>.jsonl
        self.samples = None
        self.folder: Path | None = None

    def prepare_data(self) -> None:
        self.folder = self._ensure()

    def _ensure(self) -> Path:
        from samp.robot import load_robot

        return ensure_samples(load_robot(self.robot_name), self.sample_config, self.root)

    def setup(self, stage: str | None = None) -> None:
        if self.samples is not None:
            return
        self.folder = self.folder or self._ensure()
        self.samples = s = load_samples(self.folder)
        gen = torch.Generator().manual_seed(self.seed)
        self.near_rows, self.uniform_rows, val = [], [], []
        for i in range(len(s.link_names)):
            rows = torch.nonzero(s.link == i).flatten()
            rows = rows[torch.randperm(len(rows), generator=gen)]
            n_val = max(1, int(round(self.val_fraction * len(rows))))
            val.append(rows[:n_val])
            train = rows[n_val:]
            self.near_rows.append(train[s.near[train]])
            self.uniform_rows.append(train[~s.near[train]])
        self.val_rows = torch.cat(val).sort().values

    @property
    def dataset_id(self) -> str | None:
        return self.samples.dataset_id if self.samples is not None else None

    @property
    def robot_info(self) -> SimpleNamespace:
        """name, asset_hash and link_names of the robot the samples were drawn for."""
        s = self.samples
        return SimpleNamespace(name=s.robot, asset_hash=s.robot_asset_hash, link_names=list(s.link_names))

    def train_dataloader(self):
        """Random batches from a stream of this rank's own: under DDP every rank draws its own
        `near_per_step` + `uniform_per_step` rows per link and step (rank 0 the single-process stream)."""
        from samp.data.module import rank_and_world

        rank, _ = rank_and_world(getattr(self, "trainer", None))
        record = Path(self.trainer.default_root_dir) / "draws" / f"rank{rank}.jsonl" if self.record_draws else None
        data = _RandomBatches(self.samples, self.near_rows, self.uniform_rows, self.near_per_step,
                              self.uniform_per_step, self.steps_per_epoch, self.seed + 1_000_003 * rank, record)
        return torch.utils.data.DataLoader(data, batch_size=None, shuffle=False, num_workers=0)

    def val_dataloader(self):
        s, rows = self.samples, self.val_rows
        batches = [{"points": s.points[r], "sdf": s.sdf[r], "link": s.link[r]} for r in rows.split(self.val_batch)]
        return torch.utils.data.DataLoader(batches, batch_size=None, shuffle=False, num_workers=0)


class RobotSDFSystem(pl.LightningModule):
    """Trains a link network (`net`, a partial taking `num_links`) on normalised samples.

    Args:
        net: partial constructor of the network, e.g. `UnifiedHashSDF` or `NNSDF` (conf/model/).
        robot: robot name; the network gets one input code or box per collision link.
        optimizer: partial constructor taking the parameters (conf: torch.optim.Adam, lr 2e-3).
        lr_final_factor: learning rate at the end of training relative to the start (exponential decay).
        time_limit_s: stop training after this many seconds (None: only trainer.max_steps counts).
        loss: "mse" (the paper's) or "l1", on normalised distances.
        method: the label of the method in tables and recordings (default: the network's `label`).
    """

    def __init__(self, net: Callable[..., nn.Module], robot: str, optimizer: Callable, lr_final_factor: float = 0.1,
                 time_limit_s: float | None = None, loss: str = "mse", method: str | None = None):
        super().__init__()
        from samp.robot import load_robot_config
        from samp.robot_sdf.artifact import net_spec

        if loss not in LOSSES:
            raise ValueError(f"loss must be one of {LOSSES}, got {loss!r}")
        if not 0 < lr_final_factor <= 1:
            raise ValueError(f"lr_final_factor must be in (0, 1], got {lr_final_factor}")
        self.robot_name = robot
        self.link_names = list(load_robot_config(robot).collision_links)
        kwargs = {**getattr(net, "keywords", {}), "num_links": len(self.link_names)}
        self.net = (net.func if hasattr(net, "func") else net)(**kwargs)
        self.spec = net_spec(self.net)
        self.optimizer_factory, self.lr_final_factor, self.time_limit_s = optimizer, lr_final_factor, time_limit_s
        self.loss_name = loss
        self.method = method or getattr(self.net, "label", type(self.net).__name__)
        self.register_buffer("centres", torch.zeros(len(self.link_names), 3))
        self.register_buffer("scales", torch.ones(len(self.link_names)))
        self.dataset_id: str | None = None
        self.robot_asset_hash: str | None = None
        self.train_time_s: float | None = None
        self._t0: float | None = None
        self._elapsed = 0.0
        self._val_errors: list[torch.Tensor] = []

    # ----------------------------------------------------------------- set-up
    def setup(self, stage: str) -> None:
        dm = self.trainer.datamodule if self.trainer is not None else None
        if dm is None or not hasattr(dm, "robot_info"):
            raise ValueError("RobotSDFSystem trains with a RobotSDFDataModule (trainer.fit(system, datamodule=...))")
        info = dm.robot_info
        if info.name != self.robot_name or info.link_names != self.link_names:
            raise ValueError(f"the samples are for robot {info.name!r} with links {info.link_names}, but the system is for "
                             f"{self.robot_name!r} with links {self.link_names}; use the same `robot` in both")
        self.centres.copy_(dm.samples.centres.to(self.centres))
        self.scales.copy_(dm.samples.scales.to(self.scales))
        self.dataset_id, self.robot_asset_hash = dm.dataset_id, info.asset_hash

    def configure_optimizers(self):
        optimizer = self.optimizer_factory(self.parameters())
        decay = math.log(self.lr_final_factor)
        scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda _: math.exp(decay * self._progress()))
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    def _progress(self) -> float:
        """Fraction of training done: by steps, or by time when a time limit is set and comes first."""
        trainer = self._trainer
        steps = trainer.max_steps if trainer is not None and trainer.max_steps and trainer.max_steps > 0 else None
        by_steps = self.global_step / steps if steps else 0.0
        by_time = self._elapsed / self.time_limit_s if self.time_limit_s and self._t0 else 0.0
        return min(1.0, max(by_steps, by_time))

    # ----------------------------------------------------------------- training
    def on_train_start(self) -> None:
        self._t0, self._elapsed = time.perf_counter(), 0.0

    def _sync_elapsed(self) -> None:
        """Seconds since training started, the same on every data-parallel rank (the slowest clock): the
        learning rate and the time limit follow it, so every rank steps with the same rate and stops at the
        same step (ranks that disagreed would diverge, or wait for each other forever)."""
        elapsed = time.perf_counter() - self._t0
        if self.trainer.world_size > 1:
            elapsed = float(self.trainer.strategy.reduce(torch.tensor(elapsed, dtype=torch.float64), reduce_op="max"))
        self._elapsed = elapsed

    def on_train_end(self) -> None:
        if self._t0 is not None:
            self.train_time_s = time.perf_counter() - self._t0

    def _errors_mm(self, pred: torch.Tensor, batch: dict) -> torch.Tensor:
        return (pred - batch["sdf"]) * self.scales[batch["link"]] * 1000

    def training_step(self, batch: dict, batch_idx: int) -> torch.Tensor:
        pred = self.net(batch["points"], batch["link"])
        diff = pred - batch["sdf"]
        loss = diff.square().mean() if self.loss_name == "mse" else diff.abs().mean()
        if not torch.isfinite(loss):
            raise FloatingPointError(f"the robot SDF loss is {loss.item()} at step {self.global_step}; training stopped. "
                                     "The last good checkpoint is in the run's checkpoints/ folder; lower the learning rate "
                                     "(system.optimizer.lr) and resume or restart")
        sync = self.trainer.world_size > 1  # every rank holds a part of the global batch
        self.log("train/loss", loss, prog_bar=True, sync_dist=sync)
        self.log("train/mae_mm", self._errors_mm(pred.detach(), batch).abs().mean(), sync_dist=sync)
        if self.time_limit_s and self._t0:
            self._sync_elapsed()
            if self._elapsed >= self.time_limit_s:
                self.trainer.should_stop = True
        return loss

    def validation_step(self, batch: dict, batch_idx: int) -> None:
        self._val_errors.append(self._errors_mm(self.net(batch["points"], batch["link"]), batch).detach())

    def on_validation_epoch_end(self) -> None:
        if not self._val_errors:
            return
        err = torch.cat(self._val_errors)
        self._val_errors.clear()
        sync = self.trainer.world_size > 1  # every rank validates on the whole set: the same values everywhere
        self.log("val/mae_mm", err.abs().mean(), prog_bar=True, sync_dist=sync)
        self.log("val/rmse_mm", err.square().mean().sqrt(), sync_dist=sync)

    # ----------------------------------------------------------------- export and evaluation
    def robot_sdf(self, robot=None):
        """The trained network as a `RobotSDF` for `robot` (loaded by name when not given)."""
        from samp.robot import load_robot
        from samp.robot_sdf.whole_robot import RobotSDF

        robot = robot or load_robot(self.robot_name).to(self.centres.device)
        if self.robot_asset_hash and robot.asset_hash != self.robot_asset_hash:
            raise ValueError(f"robot {robot.name!r} has asset hash {robot.asset_hash[:12]}, the samples "
                             f"{self.robot_asset_hash[:12]}; its meshes changed since the samples were drawn")
        return RobotSDF(robot, self.net, self.centres, self.scales, method=self.method)

    def on_save_checkpoint(self, checkpoint: dict) -> None:
        from samp.robot_sdf.artifact import CHECKPOINT_KEY, describe

        if self.robot_asset_hash is None:
            return
        robot = SimpleNamespace(name=self.robot_name, asset_hash=self.robot_asset_hash, link_names=self.link_names)
        checkpoint[CHECKPOINT_KEY] = describe(robot, self.spec, self.method, self.centres, self.scales, self.dataset_id,
                                              {"train_time_s": self.train_time_s})
