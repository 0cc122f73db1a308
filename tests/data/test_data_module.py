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
    dm = TrajectoryDataModule(str(folder), n_e=8, batch_size=7, noise=0.0)
    dm.setup()
    traj = dm.ds.trajectories.float()
    seen = []
    for batch in dm.train_dataloader():
        k, t = batch["traj"], batch["step"]
        assert torch.equal(batch["q"], traj[k, t]) and torch.equal(batch["q_next"], traj[k, t + 1])
        assert torch.equal(batch["q_goal"], traj[k, -1]) and torch.equal(batch["scene"], dm.ds.traj_scene[k])
        assert set(dm.ds.traj_split[k.numpy()]) == {"train"}
        seen += list(zip(k.tolist(), t.tolist()))
    n_train = int((dm.ds.traj_split == "train").sum())
    assert sorted(seen) == [(k, t) for k in range(n_train) for t in range(49)]  # every step exactly once
    for batch in dm.val_dataloader():
        assert set(dm.ds.traj_split[batch["traj"].numpy()]) == {"heldout"}
    assert dm.grids.shape == (2, 8, 8, 8)
    torch.testing.assert_close(dm.grids[1], dm.ds.scenes[1].anchor_grid(8, cache=False), rtol=0, atol=0)


def test_noise_on_q_t_only_and_within_limits(folder):
    dm = TrajectoryDataModule(str(folder), n_e=8, batch_size=64, noise=0.5)
    dm.setup()
    traj = dm.ds.trajectories.float()
    batch = next(iter(dm.train_dataloader()))
    k, t = batch["traj"], batch["step"]
    diff = batch["q"] - traj[k, t]
    assert 0.2 < float(diff.std()) < 0.6  # clamping at the limits trims it a little
    assert torch.equal(batch["q_next"], traj[k, t + 1])
    from samp.robot import load_robot_config

    cfg = load_robot_config("panda")
    assert (batch["q"] >= torch.tensor(cfg.lower) - 1e-6).all() and (batch["q"] <= torch.tensor(cfg.upper) + 1e-6).all()


def test_scene_grouped_batches_and_trajectory_split(tmp_path_factory):
    spec = {**SPEC, "name": "dm3", "train_scenes": 3, "heldout_scenes": 0, "trajectories_per_scene": 2}
    folder3 = generate(spec, root=tmp_path_factory.mktemp("datasets3"), progress=False)
    dm = TrajectoryDataModule(str(folder3), n_e=8, batch_size=10, scenes_per_batch=1, noise=0.0, val_split=0.34)
    dm.setup()
    batches = list(dm.train_dataloader())
    assert all(len(set(b["scene"].tolist())) == 1 for b in batches)
    train_k = {k for b in batches for k in b["traj"].tolist()}
    val_k = {k for b in dm.val_dataloader() for k in b["traj"].tolist()}
    assert train_k and val_k and not train_k & val_k  # split by trajectory, never by step
    assert sum(len(b["q"]) for b in batches) == len(train_k) * 49
    with pytest.raises(ValueError, match="holds out no scenes; use data.val_split"):
        TrajectoryDataModule(str(folder3), n_e=8).setup()


def test_missing_resolution_is_a_clear_error(folder):
    with pytest.raises(ValueError, match=r"stores grids at n_e in \[8\], not 40"):
        TrajectoryDataModule(str(folder), n_e=40).setup()
