"""Shared evaluation fixtures: a tiny dataset (one training, one validation and one test scene, three
evaluation problems each), built once."""

from __future__ import annotations

import pytest
import torch

TINY_EVAL = {"name": "tiny_eval", "robot": "panda", "seed": 11, "train_scenes": 1, "val_scenes": 1, "test_scenes": 1,
             "trajectories_per_scene": 1, "eval_problems_per_scene": 3, "generators": ["tabletop", "shelf"],
             "resolutions": [12, 16]}


@pytest.fixture(scope="session")
def panda(_isolated_cache):
    from samp.robot import load_robot

    return load_robot("panda", dtype=torch.float64)


@pytest.fixture(scope="session")
def tiny_eval(tmp_path_factory, _isolated_cache):
    """(dataset folder, datasets root) of TINY_EVAL (about 15 s of planning)."""
    from samp.data import generate

    root = tmp_path_factory.mktemp("eval_datasets")
    return generate(TINY_EVAL, root=root, progress=False), root


@pytest.fixture(scope="session")
def tiny_problems(tiny_eval):
    """Every evaluation problem of the tiny dataset, by split: train, val, test."""
    from samp.data import open_dataset
    from samp.eval import problems_from_dataset

    ds = open_dataset(tiny_eval[0])
    return ds, [p for split in ("train", "val", "test") for p in problems_from_dataset(ds, split)]
