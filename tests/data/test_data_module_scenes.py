"""TrajectoryDataModule(max_scenes=N) for data-scaling studies: training samples come from the first N
training scenes only, every demonstration of those scenes is kept, and validation does not change."""

from __future__ import annotations

import pytest
import torch

from samp.data import generate
from samp.data.module import TrajectoryDataModule

pytestmark = pytest.mark.slow  # generates a dataset: deselected by `make test-fast`

SPEC = {"name": "dm_scenes", "robot": "panda", "seed": 5, "train_scenes": 3, "val_scenes": 1, "test_scenes": 0,
        "trajectories_per_scene": 2, "eval_problems_per_scene": 0, "generators": ["tabletop", "shelf"],
        "resolutions": [8]}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return generate(SPEC, root=tmp_path_factory.mktemp("datasets"), progress=False)


def _trajectories(dm) -> set[int]:
    return {k for batch in dm.train_dataloader() for k in batch["traj"].tolist()}


def test_max_scenes_keeps_the_first_training_scenes(folder):
    full = TrajectoryDataModule(str(folder), n_e=8, batch_size=7, noise=0.0)
    full.setup()
    ds = full.ds
    train_scenes = [i for i, s in enumerate(ds.scene_split) if s == "train"]
    assert len(train_scenes) == 3
    for n in (1, 2, 3):
        dm = TrajectoryDataModule(str(folder), n_e=8, batch_size=7, noise=0.0, max_scenes=n)
        dm.setup()
        # the oracle: every training demonstration whose scene is among the first n training scenes
        want = {k for k in range(len(ds.traj_split)) if ds.traj_split[k] == "train"
                and int(ds.traj_scene[k]) in train_scenes[:n]}
        assert _trajectories(dm) == want and len(want) > 0
        assert torch.equal(dm.val_set.indices, full.val_set.indices)


def test_max_scenes_beyond_the_dataset_or_not_a_count_is_refused(folder):
    with pytest.raises(ValueError, match="max_scenes=4, but dataset .* has 3 training scenes"):
        TrajectoryDataModule(str(folder), n_e=8, max_scenes=4).setup()
    with pytest.raises(ValueError, match="max_scenes must be null or an integer >= 1"):
        TrajectoryDataModule(str(folder), n_e=8, max_scenes=0)
