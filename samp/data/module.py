"""The policy's DataModule: (q_t, q_{t+1}, q_goal, scene) samples from a dataset's trajectories.

A sample is one step of one expert trajectory: waypoint t, the next waypoint and the trajectory's last
waypoint as the goal. The dataset is opened once; every batch is gathered from contiguous tensors by
index (no per-sample decoding or Python objects), and the anchor grids of all scenes at the chosen n_e
are held once in `grids` (S, n_e, n_e, n_e), indexed by each sample's scene.

Splits are by scene or by trajectory, never by step (`val_split`): "val" validates on the validation
scenes' demonstrations (a fixed, seeded subset of at most `val_samples` steps); a number in (0, 1) validates
on that fraction of the training scenes' trajectories instead. Only demonstrations are read: test scenes
have none, and the dataset's evaluation problems (`Dataset.eval_problems`) are never loaded here, so
neither can reach training. Training batches get Gaussian noise on q_t
(`noise` radians, clamped to the joint limits), and are drawn from at most `scenes_per_batch` scenes each
so that the policy's 3D convolution runs once per distinct scene of a batch (0: plain random batches).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from samp.data.binding import DatasetBinding
from samp.names import (BATCH_GOAL, BATCH_NEXT, BATCH_Q, BATCH_SCENE, BATCH_START, BATCH_STEP, BATCH_STEP_CLEAN,
                        BATCH_TRAJ, SPLIT_ALIASES, SPLITS)

__all__ = ["StepSamples", "TrajectoryDataModule"]


class StepSamples(Dataset):
    """Index i -> step (trajectory k, waypoint t). `__getitem__` takes a whole batch of indices.

    With `noise` > 0, q_t gets Gaussian noise of that many radians (clamped to `limits`), drawn from a
    seeded generator; q_{t+1} and the goal stay exact.
    """

    def __init__(self, trajectories: torch.Tensor, traj_scene: torch.Tensor, rows: torch.Tensor,
                 noise: float = 0.0, limits: torch.Tensor | None = None, seed: int = 0):
        self.trajectories, self.traj_scene = trajectories, traj_scene
        steps = trajectories.shape[1] - 1
        self.k = rows.repeat_interleave(steps)
        self.t = torch.arange(steps).repeat(len(rows))
        self.scene = traj_scene[self.k]
        self.noise, self.limits = float(noise), limits
        self.generator = torch.Generator().manual_seed(seed)

    def __len__(self) -> int:
        return len(self.k)

    def __getitem__(self, index) -> dict[str, torch.Tensor]:
        index = torch.as_tensor(index)
        k, t = self.k[index], self.t[index]
        traj = self.trajectories
        q = clean = traj[k, t]
        if self.noise > 0:
            q = q + self.noise * torch.randn(q.shape, generator=self.generator, dtype=q.dtype)
            q = torch.minimum(torch.maximum(q, self.limits[:, 0]), self.limits[:, 1])
        return {BATCH_Q: q, BATCH_NEXT: traj[k, t + 1], BATCH_GOAL: traj[k, -1], BATCH_SCENE: self.traj_scene[k],
                BATCH_START: traj[k, 0], BATCH_STEP_CLEAN: clean, BATCH_TRAJ: k, BATCH_STEP: t}


class _BatchIndices(Sampler):
    """Yields whole batches of indices: in order, shuffled, or shuffled within scenes and grouped so
    that each batch holds at most `scenes_per_batch` distinct scenes. Seeded; a new order every epoch.

    Data-parallel (`world_size` > 1): every rank builds the same global batches of `batch_size` x
    `world_size` indices from the same seed and takes its own part of each (`tensor_split`, so the parts
    differ in size by at most one), so the ranks draw disjoint shares of every epoch, step for step, and the
    union of their batches at a step is the batch one process would draw with `batch_size` x `world_size`.
    `record`: a JSONL file that gets one line per batch yielded (epoch, rank, the indices, their scenes)."""

    def __init__(self, scene: torch.Tensor, batch_size: int, shuffle: bool, seed: int, drop_last: bool,
                 scenes_per_batch: int = 0, rank: int = 0, world_size: int = 1, record=None):
        if not 0 <= rank < world_size:
            raise ValueError(f"rank {rank} is not in [0, {world_size})")
        self.scene, self.n = scene, len(scene)
        self.batch_size, self.shuffle, self.seed, self.drop_last = batch_size * world_size, shuffle, seed, drop_last
        self.scenes_per_batch, self.rank, self.world_size, self.record = scenes_per_batch, rank, world_size, record
        self.epoch = 0

    def _global_batches(self) -> list[torch.Tensor]:
        g = torch.Generator().manual_seed(self.seed + self.epoch)
        if not self.shuffle:
            return list(torch.arange(self.n).split(self.batch_size))
        if self.scenes_per_batch <= 0:
            batches = list(torch.randperm(self.n, generator=g).split(self.batch_size))
            return batches[:-1] if self.drop_last and len(batches[-1]) < self.batch_size else batches
        # Shuffled chunks of one scene each, batch_size / scenes_per_batch long; every scenes_per_batch
        # consecutive chunks form a batch. Only a scene's last chunk can be short, so batches are full
        # but for a few slightly smaller ones, and none spans more than scenes_per_batch scenes.
        chunk = max(1, -(-self.batch_size // self.scenes_per_batch))
        chunks = []
        for s in self.scene.unique():
            rows = (self.scene == s).nonzero()[:, 0]
            chunks += list(rows[torch.randperm(len(rows), generator=g)].split(chunk))
        chunks = [chunks[i] for i in torch.randperm(len(chunks), generator=g).tolist()]
        k = self.scenes_per_batch
        return [torch.cat(chunks[i:i + k]) for i in range(0, len(chunks), k)]

    def _batches(self) -> list[torch.Tensor]:
        batches = self._global_batches()
        if self.world_size == 1:
            return batches
        # every rank gets a part of every global batch; a batch too small to give each rank a sample is dropped
        return [b.tensor_split(self.world_size)[self.rank] for b in batches if len(b) >= self.world_size]

    def set_epoch(self, epoch: int) -> None:
        """Lightning calls this before every epoch (`_set_sampler_epoch`): a resumed run draws the order of
        the epoch it resumes in, not the first epoch's again."""
        self.epoch = int(epoch) if self.shuffle else 0

    def __iter__(self):
        batches, epoch = self._batches(), self.epoch
        self.epoch += int(self.shuffle)  # without a caller of set_epoch: the next epoch's order next time
        for batch in batches:
            if self.record is not None:
                _append_json(self.record, {"epoch": epoch, "rank": self.rank, "world_size": self.world_size,
                                           "indices": batch.tolist(), "scenes": self.scene[batch].tolist()})
            yield batch

    def __len__(self) -> int:
        return len(self._batches())


def _append_json(path, record: dict) -> None:
    import json
    from pathlib import Path

    Path(path).parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a") as f:
        f.write(json.dumps(record) + "\n")


def rank_and_world(trainer) -> tuple[int, int]:
    """(global rank, world size) of the Trainer a data module is attached to; (0, 1) without one."""
    if trainer is None:
        return 0, 1
    return int(trainer.global_rank), int(trainer.world_size)


class TrajectoryDataModule(pl.LightningDataModule):
    """Args:
        dataset: a reference (`name`, `name@id` or a folder); root: the registry folder (None: default).
        n_e: the grid resolution (must be stored in the dataset).
        batch_size: samples per batch (the paper: 50). scenes_per_batch: distinct scenes per training batch
            (0: plain random batches). noise: std of the Gaussian noise on training q_t (radians).
        val_split: "val" (validate on the validation scenes' demonstrations; "heldout", its older name, is a
            deprecated synonym) or a fraction in (0, 1) of the training scenes' trajectories.
        val_samples: steps per validation pass (a fixed, seeded subset).
        max_trajectories: use at most this many training trajectories (None: all), for quick runs.
        max_scenes: train on the demonstrations of the first this many training scenes only (None: all), for
            data-scaling studies (`conf/sweep/data_scaling.yaml`); validation is unchanged.
        record_draws: write the indices and scenes of every training batch each rank draws to
            `<run>/draws/rank<r>.jsonl` (to audit what data-parallel ranks trained on).

    After `setup`, `binding` is what a model trained on this data depends on (`DatasetBinding`). A missing
    dataset is an error here; the training recipe builds it first when asked (`build_missing.dataset`).
    """

    def __init__(self, dataset: str, n_e: int = 40, batch_size: int = 50, scenes_per_batch: int = 2,
                 noise: float = 0.03, val_split: str | float = "val", val_samples: int = 2000,
                 max_trajectories: int | None = None, max_scenes: int | None = None, seed: int = 0,
                 root: str | None = None, record_draws: bool = False):
        super().__init__()
        if val_split in SPLIT_ALIASES:
            warnings.warn(f"val_split={val_split!r} is deprecated: write val_split='{SPLIT_ALIASES[val_split]}' (the "
                          "validation scenes)", DeprecationWarning, stacklevel=2)
            val_split = SPLIT_ALIASES[val_split]
        if not (val_split == "val" or (isinstance(val_split, (int, float)) and not isinstance(val_split, bool)
                                       and 0 < val_split < 1)):
            raise ValueError(f"val_split must be 'val' (the validation scenes) or a fraction in (0, 1) of the training "
                             f"trajectories, got {val_split!r}")
        if max_scenes is not None and (isinstance(max_scenes, bool) or not isinstance(max_scenes, int) or max_scenes < 1):
            raise ValueError(f"max_scenes must be null or an integer >= 1, got {max_scenes!r}")
        if batch_size < 1 or scenes_per_batch < 0 or noise < 0:
            raise ValueError(f"batch_size >= 1, scenes_per_batch >= 0 and noise >= 0 expected; got {batch_size}, "
                             f"{scenes_per_batch}, {noise}")
        self.ref, self.n_e, self.batch_size, self.val_samples = dataset, int(n_e), int(batch_size), int(val_samples)
        self.scenes_per_batch, self.noise, self.val_split = int(scenes_per_batch), float(noise), val_split
        self.max_trajectories, self.max_scenes, self.seed, self.root = max_trajectories, max_scenes, int(seed), root
        self.record_draws = bool(record_draws)
        self.ds = None
        self.binding: DatasetBinding | None = None

    def setup(self, stage: str | None = None) -> None:
        if self.ds is not None:
            return
        from pathlib import Path

        from samp.data.dataset import open_dataset
        from samp.robot import load_robot_config

        ds = open_dataset(self.ref, Path(self.root) if self.root else None)
        if self.n_e not in ds.resolutions:
            raise ValueError(f"dataset {ds.name}@{ds.id} stores grids at n_e in {ds.resolutions}, not {self.n_e}: set "
                             f"datamodule.n_e to one of them or regenerate the dataset with n_e in its spec's resolutions")
        if len(ds) == 0:
            raise ValueError(f"dataset {ds.name}@{ds.id} holds no successful trajectories to train on")
        self.ds, self.dataset_id = ds, f"{ds.name}@{ds.id}"
        self.robot_name = ds.manifest["robot"]["name"]
        self.robot_asset_hash = ds.manifest["robot"]["asset_hash"]
        self.bounds = ds.scenes[0].bounds
        if any(s.bounds != self.bounds for s in ds.scenes):
            raise ValueError(f"dataset {self.dataset_id}: scenes with different workspace bounds cannot share a policy")
        self.grids = ds.grids(self.n_e)  # (S, n, n, n) float32
        self.binding = DatasetBinding(self.robot_name, self.robot_asset_hash, self.dataset_id, self.n_e, self.bounds,
                                      self.grids)
        self.trajectories = ds.trajectories.float()
        cfg = load_robot_config(self.robot_name)
        limits = torch.tensor([cfg.lower, cfg.upper], dtype=torch.float32).T
        g = torch.Generator().manual_seed(self.seed)
        train = torch.from_numpy(np.flatnonzero(ds.traj_split == "train"))
        if self.val_split == "val":
            val = torch.from_numpy(np.flatnonzero(ds.traj_split == "val"))
            if len(val) == 0:
                per_split = {s: ds.scene_split.count(s) for s in SPLITS}
                raise ValueError(f"dataset {self.dataset_id} has no validation demonstrations (scenes per split: "
                                 f"{per_split}); use data.val_split=0.1 to validate on a fraction of the training "
                                 "trajectories, or generate a dataset with val_scenes > 0")
        else:
            train = train[torch.randperm(len(train), generator=g)]
            cut = max(1, int(round(self.val_split * len(train))))
            train, val = train[cut:].sort().values, train[:cut].sort().values
        if self.max_scenes is not None:
            scenes = [i for i, split in enumerate(ds.scene_split) if split == "train"]
            if self.max_scenes > len(scenes):
                raise ValueError(f"max_scenes={self.max_scenes}, but dataset {self.dataset_id} has {len(scenes)} training "
                                 "scenes")
            train = train[torch.isin(ds.traj_scene[train], torch.tensor(scenes[: self.max_scenes]))]
        if self.max_trajectories is not None:
            train = train[: int(self.max_trajectories)]
        if len(train) == 0:
            raise ValueError(f"dataset {self.dataset_id} leaves no training trajectories")
        self.train_samples = StepSamples(self.trajectories, ds.traj_scene, train, self.noise, limits, self.seed)
        self.val_all = StepSamples(self.trajectories, ds.traj_scene, val)
        pick = torch.randperm(len(self.val_all), generator=g)[: self.val_samples]
        self.val_set = _Subset(self.val_all, pick.sort().values)

    def train_dataloader(self) -> DataLoader:
        """Each rank's part of every global batch (`_BatchIndices`): `batch_size` is per rank, so a DDP step
        trains on `batch_size` x world size samples. The noise on q_t is drawn from a stream per rank."""
        rank, world = rank_and_world(getattr(self, "trainer", None))
        self.train_samples.generator.manual_seed(self.seed + 1_000_003 * rank)  # rank 0: the single-process stream
        record = None
        if self.record_draws:
            from pathlib import Path

            record = Path(self.trainer.default_root_dir) / "draws" / f"rank{rank}.jsonl"
        sampler = _BatchIndices(self.train_samples.scene, self.batch_size, True, self.seed, drop_last=True,
                                scenes_per_batch=self.scenes_per_batch, rank=rank, world_size=world, record=record)
        return DataLoader(self.train_samples, sampler=sampler, batch_size=None, num_workers=0)

    def val_dataloader(self) -> DataLoader:
        """The whole validation set on every rank (not split): every rank computes the same values, so the
        metrics rank 0 logs and the checkpoint choice hold for the whole run."""
        scene = self.val_all.scene[self.val_set.indices]
        sampler = _BatchIndices(scene, self.batch_size, False, self.seed, drop_last=False)
        return DataLoader(self.val_set, sampler=sampler, batch_size=None, num_workers=0)


class _Subset(Dataset):
    def __init__(self, samples: StepSamples, indices: torch.Tensor):
        self.samples, self.indices = samples, indices

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index):
        return self.samples[self.indices[torch.as_tensor(index)]]
