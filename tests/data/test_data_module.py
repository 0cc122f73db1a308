"""TrajectoryDataModule: every sample is (waypoint t, waypoint t + 1, last waypoint) of one trajectory,
training from training scenes and validation from validation scenes, with the grids of each scene; test
scenes and evaluation problems never reach a batch."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.data import generate
from samp.data.module import TrajectoryDataModule

SPEC = {"name": "dm", "robot": "panda", "seed": 3, "train_scenes": 1, "val_scenes": 1, "test_scenes": 1,
        "trajectories_per_scene": 2, "eval_problems_per_scene": 2, "generators": ["tabletop"], "resolutions": [8]}


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
        assert set(dm.ds.traj_split[batch["traj"].numpy()]) == {"val"}
    assert dm.grids.shape == (3, 8, 8, 8)
    torch.testing.assert_close(dm.grids[1], dm.ds.scenes[1].anchor_grid(8, cache=False), rtol=0, atol=0)


def test_batches_hold_no_test_scene_and_no_evaluation_problem(folder):
    """Compared by value: no training or validation sample comes from a test scene, and no waypoint of a
    batch (q_t without noise, q_{t+1}, start, goal) is a start, goal or solution waypoint of an
    evaluation problem."""
    dm = TrajectoryDataModule(str(folder), n_e=8, batch_size=16, noise=0.0)
    dm.setup()
    ds = dm.ds
    test_scenes = ds.scene_indices("test")
    assert test_scenes == [2] and len(ds.eval_problems) == 6
    held = [np.asarray(p[k], dtype=np.float64)[None] for p in ds.eval_problems for k in ("start", "goal")]
    held += [p["solution"] for p in ds.eval_problems if p["success"]]
    held = torch.from_numpy(np.concatenate(held)).float()  # (H, n) every configuration of an evaluation problem
    batches = list(dm.train_dataloader()) + list(dm.val_dataloader())
    assert batches and sum(len(b["q"]) for b in batches) > 0
    for batch in batches:
        assert not set(batch["scene"].tolist()) & set(test_scenes), "a test scene reached a batch"
        for key in ("q_clean", "q_next", "q_start", "q_goal"):
            same = (batch[key][:, None, :] == held[None]).all(dim=-1)  # (B, H)
            assert not bool(same.any()), f"batch[{key!r}] holds a configuration of an evaluation problem"


def test_heldout_is_a_deprecated_synonym_of_val(folder):
    with pytest.warns(DeprecationWarning, match="val_split='heldout' is deprecated: write val_split='val'"):
        old = TrajectoryDataModule(str(folder), n_e=8, batch_size=7, noise=0.0, val_split="heldout")
    new = TrajectoryDataModule(str(folder), n_e=8, batch_size=7, noise=0.0)
    old.setup()
    new.setup()
    assert torch.equal(old.val_set.indices, new.val_set.indices) and len(new.val_set) > 0
    assert [b["traj"].tolist() for b in old.val_dataloader()] == [b["traj"].tolist() for b in new.val_dataloader()]
    with pytest.raises(ValueError, match=r"val_split must be 'val' \(the validation scenes\) or a fraction"):
        TrajectoryDataModule(str(folder), val_split="test")


def test_noise_on_q_t_only_and_within_limits(folder):
    dm = TrajectoryDataModule(str(folder), n_e=8, batch_size=64, noise=0.5)
    dm.setup()
    traj = dm.ds.trajectories.float()
    batch = next(iter(dm.train_dataloader()))
    k, t = batch["traj"], batch["step"]
    diff = batch["q"] - traj[k, t]
    assert 0.2 < float(diff.std()) < 0.6  # clamping at the limits trims it a little
    # Small noise, rarely clamped: the std of 64 x 7 = 448 draws is 0.05 within ~3.4 % (1 sigma = 1 / sqrt(2 N));
    # +-15 % is over 4 sigma. Catches the variance used as the std (0.0025) and noise applied twice (0.071).
    small = TrajectoryDataModule(str(folder), n_e=8, batch_size=64, noise=0.05)
    small.setup()
    batch = next(iter(small.train_dataloader()))
    diff = batch["q"] - traj[batch["traj"], batch["step"]]
    assert 0.0425 < float(diff.std()) < 0.0575, f"noise std: expected 0.05, got {float(diff.std()):.4f}"
    assert abs(float(diff.mean())) < 0.05 * 4 / 448 ** 0.5, f"noise mean: expected 0, got {float(diff.mean()):.4f}"
    assert torch.equal(batch["q_next"], traj[k, t + 1])
    from samp.robot import load_robot_config

    cfg = load_robot_config("panda")
    assert (batch["q"] >= torch.tensor(cfg.lower) - 1e-6).all() and (batch["q"] <= torch.tensor(cfg.upper) + 1e-6).all()


def test_scene_grouped_batches_and_trajectory_split(tmp_path_factory):
    spec = {**SPEC, "name": "dm3", "train_scenes": 3, "val_scenes": 0, "test_scenes": 0, "trajectories_per_scene": 2,
            "eval_problems_per_scene": 0}
    folder3 = generate(spec, root=tmp_path_factory.mktemp("datasets3"), progress=False)
    dm = TrajectoryDataModule(str(folder3), n_e=8, batch_size=10, scenes_per_batch=1, noise=0.0, val_split=0.34)
    dm.setup()
    batches = list(dm.train_dataloader())
    assert all(len(set(b["scene"].tolist())) == 1 for b in batches)
    train_k = {k for b in batches for k in b["traj"].tolist()}
    val_k = {k for b in dm.val_dataloader() for k in b["traj"].tolist()}
    assert train_k and val_k and not train_k & val_k  # split by trajectory, never by step
    assert sum(len(b["q"]) for b in batches) == len(train_k) * 49
    with pytest.raises(ValueError, match=r"has no validation demonstrations \(scenes per split: \{'train': 3, 'val': 0, "
                                         r"'test': 0\}\); use data.val_split=0.1"):
        TrajectoryDataModule(str(folder3), n_e=8).setup()


def test_missing_resolution_is_a_clear_error(folder):
    with pytest.raises(ValueError, match=r"stores grids at n_e in \[8\], not 40"):
        TrajectoryDataModule(str(folder), n_e=40).setup()


def test_a_legacy_dataset_validates_on_its_heldout_scenes(folder, tmp_path):
    """A dataset from before issue 17 (scene 1 labelled "heldout", no evaluation problems) trains as before:
    its held-out scene validates."""
    from samp.data import open_dataset, write_dataset

    ds = open_dataset(folder)
    ds.scene_split[1] = "heldout"
    ds.eval_problems, ds.has_eval_problems = [], False
    dm = TrajectoryDataModule(str(write_dataset(ds, name="legacy", root=tmp_path)), n_e=8, batch_size=7, noise=0.0)
    dm.setup()
    assert dm.ds.legacy_splits and dm.ds.scene_split == ["train", "val", "test"]
    assert {s for b in dm.val_dataloader() for s in b["scene"].tolist()} == {1}
    assert {s for b in dm.train_dataloader() for s in b["scene"].tolist()} == {0}
