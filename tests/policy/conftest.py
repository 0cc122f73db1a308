"""Shared fixtures of the policy and baseline tests: one tiny dataset (generated once per session) and a
small robot SDF."""

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


@pytest.fixture(scope="session")
def small_robot_sdf():
    """(robot, spread=False) -> a small untrained hash-grid robot SDF in the artifact format (a policy
    checkpoint's robot_sdf payload). `spread` draws its hash tables from U(-1, 1), so that its values, and
    the pairs a robot-point query must evaluate, are far from zero."""
    import torch

    from samp.robot_sdf.artifact import describe, net_spec
    from samp.robot_sdf.model import UnifiedHashSDF
    from samp.robot_sdf.samples import link_normalisation

    def make(robot, spread: bool = False) -> dict:
        torch.manual_seed(0)
        kwargs = {"num_links": len(robot.link_names), "encoding": {"levels": 4, "log2_table_size": 10, "finest": 64},
                  "hidden": [16]}
        net = UnifiedHashSDF(**kwargs)
        if spread:
            with torch.no_grad():
                for table in net.encoder.tables:
                    table.uniform_(-1, 1)
        centres, scales = link_normalisation(robot, 0.02)
        info = describe(robot, net_spec(net, kwargs), "test", torch.tensor(centres), torch.tensor(scales))
        return {"info": info, "state_dict": net.state_dict(), "artifact_id": "test"}

    return make
