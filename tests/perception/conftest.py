"""Shared perception fixtures: a robot, and a table with one box seen by small cameras from every side."""

from __future__ import annotations

import pytest
import torch

BOX_BOUNDS = ((0.35, -0.3, 0.02), (0.95, 0.3, 0.42))  # around the box only: finer voxels at a small n_e


@pytest.fixture(scope="session")
def panda(_isolated_cache):
    from samp.robot import load_robot

    return load_robot("panda", dtype=torch.float64)


@pytest.fixture(scope="session")
def box_scene():
    """A 20 x 16 x 24 cm box on a table, clear of the robot at home."""
    from samp.scene import Box, Pose, Scene
    from samp.scene.generators import table

    box = Box("box", (0.2, 0.16, 0.24), Pose.from_xyz_yaw(0.65, 0.0, 0.12, 0.3))
    return Scene("one_box", obstacles=(table(), box), bounds=BOX_BOUNDS)


def _ring_cameras(name: str = "ring", count: int = 4, top: bool = True, size=(96, 72), **noise):
    """`count` cameras around the box (and one above), 1.2 m away, as a camera set mapping."""
    import numpy as np

    cameras = []
    for i in range(count):
        a = 2 * np.pi * (i + 0.5) / count  # diagonals: no camera looks at the box through the robot
        cameras.append({"name": f"side{i}", "eye": [0.65 + 1.2 * np.cos(a), 1.2 * np.sin(a), 0.8],
                        "target": [0.65, 0.0, 0.1]})
    if top:
        cameras.append({"name": "top", "eye": [0.65, 0.0, 1.5], "target": [0.65, 0.0, 0.0], "up": [1.0, 0.0, 0.0]})
    return {"name": name, "seed": 0, "cameras": cameras,
            "common": {"width": size[0], "height": size[1], "fov": 60.0, **noise}}


@pytest.fixture(scope="session")
def ring_cameras():
    """`ring_cameras(name, count, top, size, **noise)`: a camera set around the box (a fixture, not an import of
    conftest, so that the tests also run under `--import-mode=importlib`)."""
    return _ring_cameras


TINY_PERCEPTION = {"name": "tiny_perception", "robot": "panda", "seed": 11, "train_scenes": 1, "val_scenes": 1,
                   "trajectories_per_scene": 2, "eval_problems_per_scene": 2, "generators": ["tabletop"],
                   "resolutions": [12]}


@pytest.fixture(scope="session")
def tiny_dataset(tmp_path_factory, _isolated_cache):
    """A dataset folder of TINY_PERCEPTION (a few seconds of planning)."""
    from samp.data import generate

    return generate(TINY_PERCEPTION, root=tmp_path_factory.mktemp("perception_datasets"), progress=False)


@pytest.fixture(scope="session")
def small_cameras_yaml(tmp_path_factory):
    """A camera set file like conf/camera/default.yaml, with small images around the whole table."""
    import yaml

    data = {"_target_": "samp.sim.camera.camera_set", "name": "small", "seed": 0,
            "common": {"width": 64, "height": 48, "fov": 70.0, "depth_noise": 0.002, "dropout": 0.01},
            "cameras": [{"name": "front", "eye": [2.0, 0.0, 1.2], "target": [0.3, 0.0, 0.15]},
                        {"name": "left", "eye": [0.4, 1.9, 1.2], "target": [0.3, 0.0, 0.15]},
                        {"name": "right", "eye": [0.4, -1.9, 1.2], "target": [0.3, 0.0, 0.15]},
                        {"name": "top", "eye": [0.3, 0.0, 2.4], "target": [0.3, 0.0, 0.0], "up": [1.0, 0.0, 0.0]}]}
    path = tmp_path_factory.mktemp("cameras") / "small.yaml"
    path.write_text(yaml.safe_dump(data))
    return path
