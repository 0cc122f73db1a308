"""Shared fixtures of the baseline tests: one tiny dataset, generated once per session."""

from __future__ import annotations

import pytest

TINY = {"name": "bl_tiny", "robot": "panda", "seed": 7, "train_scenes": 1, "val_scenes": 1,
        "trajectories_per_scene": 3, "eval_problems_per_scene": 3, "generators": ["tabletop"], "resolutions": [16]}


@pytest.fixture(scope="session")
def tiny(tmp_path_factory, robots):
    """(dataset folder, datasets root) of TINY."""
    from samp.data import generate

    root = tmp_path_factory.mktemp("baselines_datasets")
    return generate(TINY, root=root, progress=False), root


@pytest.fixture(scope="session")
def tiny_datamodule(tiny):
    """batch_size -> a set-up TrajectoryDataModule over TINY at n_e = 16, without noise."""
    from samp.data.module import TrajectoryDataModule

    def make(batch_size: int):
        module = TrajectoryDataModule(str(tiny[0]), n_e=16, batch_size=batch_size, noise=0.0)
        module.setup()
        return module

    return make

