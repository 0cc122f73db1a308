"""The contract between a dataset and the model trained on it: one frozen `DatasetBinding`.

A DataModule hands it to the system at fit start (`TrajectoryDataModule.binding`); the system checks the
robot, keeps the grids as a non-persistent buffer and saves the rest (`meta()`) in its checkpoint, from
which `DatasetBinding.from_meta` restores it without grids. Nothing else about the dataset is read by a
model, and the model's hyperparameters are never rewritten during `fit`.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import torch

__all__ = ["DatasetBinding"]


@dataclass(frozen=True)
class DatasetBinding:
    """What a policy trained on a dataset depends on.

    Attributes:
        robot, robot_asset_hash: the robot the dataset was generated for (name, sha256 of URDF + meshes).
        dataset_id: `name@id` of the dataset.
        n_e: anchors per axis of the grids the policy reads.
        bounds: ((x, y, z) min, (x, y, z) max) workspace bounds of every scene, metres.
        grids: (S, n_e, n_e, n_e) float32 anchor grids of the dataset's scenes, or None (a binding read
            back from a checkpoint: scenes come with each rollout instead).
    """

    robot: str
    robot_asset_hash: str
    dataset_id: str
    n_e: int
    bounds: tuple
    grids: torch.Tensor | None = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        if int(self.n_e) < 2:
            raise ValueError(f"a binding needs n_e >= 2 anchors per axis, got {self.n_e}")
        bounds = tuple(tuple(float(v) for v in row) for row in self.bounds)
        if len(bounds) != 2 or any(len(row) != 3 for row in bounds):
            raise ValueError(f"bounds must be ((x, y, z) min, (x, y, z) max), got {self.bounds!r}")
        object.__setattr__(self, "bounds", bounds)
        object.__setattr__(self, "n_e", int(self.n_e))
        if self.grids is not None and tuple(self.grids.shape[1:]) != (self.n_e,) * 3:
            raise ValueError(f"grids of shape {tuple(self.grids.shape)} do not match n_e = {self.n_e}")

    def meta(self) -> dict:
        """The binding without its grids, JSON-ready (saved in checkpoints)."""
        return {"robot": self.robot, "robot_asset_hash": self.robot_asset_hash, "dataset_id": self.dataset_id,
                "n_e": self.n_e, "bounds": [list(row) for row in self.bounds]}

    @classmethod
    def from_meta(cls, meta: dict) -> "DatasetBinding":
        """The inverse of `meta()`; ValueError naming the missing keys."""
        missing = sorted({"robot", "robot_asset_hash", "dataset_id", "n_e", "bounds"} - set(meta))
        if missing:
            raise ValueError(f"a dataset binding record lacks {missing}; got keys {sorted(meta)}")
        return cls(meta["robot"], meta["robot_asset_hash"], meta["dataset_id"], meta["n_e"], meta["bounds"])

    def without_grids(self) -> "DatasetBinding":
        return replace(self, grids=None)
