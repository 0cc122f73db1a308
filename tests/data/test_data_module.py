"""TrajectoryDataModule: every sample is (waypoint t, waypoint t + 1, last waypoint) of one trajectory,
training from training scenes and validation from held-out scenes, with the grids of each scene."""

from __future__ import annotations

import pytest
import torch

from samp.data import generate
from samp.data.module import TrajectoryDataModule

SPEC = {"name": "dm", "robot": "panda", "seed": 3, "train_scenes": 1, "heldout_scenes": 1,
        "trajectories_per_scene": 2, "generators": ["tabletop"], "resolutions": [8]}


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    return generate(SPEC, root=tmp_path_factory.mktemp("datasets"), progress=False)


def test_samples_match_the_trajectories(folder):
    dm = TrajectoryDataModule(str(folder), n_e=8, batch_size=7)
    dm.setup()
    traj = dm.ds.trajectories.float()
    seen = set()
    for batch in dm.train_dataloader():
        k, t = batch["traj"], batch["step"]
        assert torch.equal(batch["q"], traj[k, t]) and torch.equal(batch["q_next"], traj[k, t + 1])
        assert torch.equal(batch["q_goal"], traj[k, -1]) and torch.equal(batch["scene"], dm.ds.traj_scene[k])
        assert set(dm.ds.traj_split[k.numpy()]) == {"train"}
        seen |= set(zip(k.tolist(), t.tolist()))
    n_train = int((dm.ds.traj_split == "train").sum())
    assert len(seen) == n_train * 49 - (n_train * 49) % 7  # every step once per epoch (last partial batch dropped)
    for batch in dm.val_dataloader():
        assert set(dm.ds.traj_split[batch["traj"].numpy()]) == {"heldout"}
    assert dm.grids.shape == (2, 8, 8, 8)
    torch.testing.assert_close(dm.grids[1], dm.ds.scenes[1].anchor_grid(8, cache=False), rtol=0, atol=0)


def test_missing_resolution_is_a_clear_error(folder):
    with pytest.raises(ValueError, match=r"stores grids at n_e in \[8\], not 40"):
        TrajectoryDataModule(str(folder), n_e=40).setup()
