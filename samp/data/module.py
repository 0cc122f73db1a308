"""The policy's DataModule: (q_t, q_{t+1}, q_goal, scene) samples from a dataset's trajectories.

A sample is one step of one expert trajectory: waypoint t, the next waypoint and the trajectory's last
waypoint as the goal. The dataset is opened once; every batch is gathered from contiguous tensors by
index (no per-sample decoding or Python objects), and the anchor grids of all scenes at the chosen n_e
are held once in `grids` (S, n_e, n_e, n_e), indexed by each sample's scene.

Training samples come from the training scenes; validation from the held-out scenes (a fixed, seeded
subset of at most `val_samples`), or from the training scenes when the dataset holds out none.
"""

from __future__ import annotations

import numpy as np
import pytorch_lightning as pl
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

__all__ = ["StepSamples", "TrajectoryDataModule"]


class StepSamples(Dataset):
    """Index i -> step (trajectory k, waypoint t). `__getitem__` takes a whole batch of indices."""

    def __init__(self, trajectories: torch.Tensor, traj_scene: torch.Tensor, rows: torch.Tensor):
        self.trajectories, self.traj_scene = trajectories, traj_scene
        steps = trajectories.shape[1] - 1
        self.k = rows.repeat_interleave(steps)
        self.t = torch.arange(steps).repeat(len(rows))

    def __len__(self) -> int:
        return len(self.k)

    def __getitem__(self, index) -> dict[str, torch.Tensor]:
        index = torch.as_tensor(index)
        k, t = self.k[index], self.t[index]
        traj = self.trajectories
        return {"q": traj[k, t], "q_next": traj[k, t + 1], "q_goal": traj[k, -1], "scene": self.traj_scene[k],
                "traj": k, "step": t}


class _BatchIndices(Sampler):
    """Yields whole batches of indices (shuffled with a seeded generator per epoch, or in order)."""

    def __init__(self, n: int, batch_size: int, shuffle: bool, seed: int, drop_last: bool):
        self.n, self.batch_size, self.shuffle, self.seed, self.drop_last = n, batch_size, shuffle, seed, drop_last
        self.epoch = 0

    def __iter__(self):
        if self.shuffle:
            order = torch.randperm(self.n, generator=torch.Generator().manual_seed(self.seed + self.epoch))
            self.epoch += 1
        else:
            order = torch.arange(self.n)
        stop = self.n - self.n % self.batch_size if self.drop_last else self.n
        for i in range(0, stop, self.batch_size):
            yield order[i:i + self.batch_size]

    def __len__(self) -> int:
        return self.n // self.batch_size if self.drop_last else -(-self.n // self.batch_size)


class TrajectoryDataModule(pl.LightningDataModule):
    """Args:
        dataset: a reference (`name`, `name@id` or a folder). n_e: the grid resolution (stored in the dataset).
        batch_size: samples per batch (the paper: 50). val_samples: held-out steps per validation pass.
        max_trajectories: use at most this many training trajectories (None: all), for quick runs.
    """

    def __init__(self, dataset: str, n_e: int = 40, batch_size: int = 50, val_samples: int = 2000,
                 max_trajectories: int | None = None, seed: int = 0, root: str | None = None):
        super().__init__()
        self.ref, self.n_e, self.batch_size, self.val_samples = dataset, int(n_e), int(batch_size), int(val_samples)
        self.max_trajectories, self.seed, self.root = max_trajectories, int(seed), root
        self.ds = None

    def setup(self, stage: str | None = None) -> None:
        if self.ds is not None:
            return
        from pathlib import Path

        from samp.data.dataset import open_dataset

        ds = open_dataset(self.ref, Path(self.root) if self.root else None)
        if self.n_e not in ds.resolutions:
            raise ValueError(f"dataset {ds.name}@{ds.id} stores grids at n_e in {ds.resolutions}, not {self.n_e}: set "
                             f"data.n_e to one of them or regenerate the dataset with n_e in its spec's resolutions")
        if len(ds) == 0:
            raise ValueError(f"dataset {ds.name}@{ds.id} holds no successful trajectories to train on")
        self.ds = ds
        self.dataset_id = f"{ds.name}@{ds.id}"
        self.bounds = ds.scenes[0].bounds
        if any(s.bounds != self.bounds for s in ds.scenes):
            raise ValueError(f"dataset {self.dataset_id}: scenes with different workspace bounds cannot share a policy")
        self.grids = ds.grids(self.n_e)  # (S, n, n, n) float32
        self.trajectories = ds.trajectories.float()
        train = torch.from_numpy(np.flatnonzero(ds.traj_split == "train"))
        held = torch.from_numpy(np.flatnonzero(ds.traj_split == "heldout"))
        if self.max_trajectories is not None:
            train = train[: int(self.max_trajectories)]
        if len(train) == 0:
            raise ValueError(f"dataset {self.dataset_id} has no training trajectories")
        self.train_samples = StepSamples(self.trajectories, ds.traj_scene, train)
        val_rows = held if len(held) else train
        val_all = StepSamples(self.trajectories, ds.traj_scene, val_rows)
        pick = torch.randperm(len(val_all), generator=torch.Generator().manual_seed(self.seed))[: self.val_samples]
        self.val_indices = pick.sort().values
        self.val_samples_set = val_all

    def _loader(self, samples: Dataset, n: int, shuffle: bool, indices: torch.Tensor | None = None) -> DataLoader:
        sampler = _BatchIndices(n, self.batch_size, shuffle, self.seed, drop_last=shuffle)
        if indices is not None:
            samples = _Subset(samples, indices)
        return DataLoader(samples, sampler=sampler, batch_size=None, num_workers=0)

    def train_dataloader(self) -> DataLoader:
        return self._loader(self.train_samples, len(self.train_samples), shuffle=True)

    def val_dataloader(self) -> DataLoader:
        return self._loader(self.val_samples_set, len(self.val_indices), shuffle=False, indices=self.val_indices)


class _Subset(Dataset):
    def __init__(self, samples: StepSamples, indices: torch.Tensor):
        self.samples, self.indices = samples, indices

    def __len__(self) -> int:
        return len(self.indices)

    def __getitem__(self, index):
        return self.samples[self.indices[torch.as_tensor(index)]]
