"""Robot configs: every file composes and loads; bad input fails with a message that helps."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import yaml
from hydra import compose, initialize_config_dir

from samp.paths import conf_dir
from samp.robot import available_robots, load_robot, load_robot_config

ROBOT_FILES = sorted((conf_dir() / "robot").glob("*.yaml"))


def test_every_robot_file_is_listed():
    assert [p.stem for p in ROBOT_FILES] == available_robots()
    assert {"panda", "iiwa", "xarm6"} <= set(available_robots())


@pytest.mark.parametrize("path", ROBOT_FILES, ids=lambda p: p.stem)
def test_robot_file_composes_and_loads(path, robots):
    with initialize_config_dir(config_dir=str(conf_dir()), version_base="1.3"):
        cfg = compose(config_name="robot_show", overrides=[f"robot={path.stem}"])
    robot = robots.get(path.stem) or load_robot(cfg.robot, dtype=torch.float64)
    composed = load_robot_config(cfg.robot)
    assert composed.name == path.stem == robot.name
    assert robot.joint_names == list(cfg.robot.joints)
    assert robot.joint_limits.shape == (robot.dof, 2)
    assert torch.all(robot.joint_limits[:, 0] < robot.joint_limits[:, 1])
    assert set(robot.link_meshes) == set(cfg.robot.collision_links)
    for name, mesh in robot.link_meshes.items():
        assert mesh.is_watertight and mesh.area > 0, f"{path.stem}/{name}: link mesh must be closed"


def test_gripper_opening_is_configurable(robots):
    cfg = yaml.safe_load((conf_dir() / "robot" / "panda.yaml").read_text())
    cfg["gripper"]["opening"] = 0.01
    narrow = load_robot(cfg, dtype=torch.float64)
    q = robots["panda"].home[None]
    y_wide = robots["panda"].fk(q)["panda_leftfinger"][0, :3, 3] - robots["panda"].fk(q)["panda_rightfinger"][0, :3, 3]
    y_narrow = narrow.fk(q)["panda_leftfinger"][0, :3, 3] - narrow.fk(q)["panda_rightfinger"][0, :3, 3]
    assert torch.linalg.norm(y_wide).item() == pytest.approx(0.08, abs=1e-9)
    assert torch.linalg.norm(y_narrow).item() == pytest.approx(0.02, abs=1e-9)


def _panda_yaml(tmp_path: Path, **changes) -> Path:
    cfg = yaml.safe_load((conf_dir() / "robot" / "panda.yaml").read_text())
    cfg.update(changes)
    path = tmp_path / "robot.yaml"
    path.write_text(yaml.safe_dump(cfg))
    return path


def test_unknown_robot_lists_the_available_ones():
    with pytest.raises(ValueError, match=r"unknown robot 'ur5'; available robots: iiwa, panda, xarm6"):
        load_robot("ur5")


def test_link_without_collision_mesh(tmp_path):
    cfg = yaml.safe_load((conf_dir() / "robot" / "panda.yaml").read_text())
    path = _panda_yaml(tmp_path, collision_links=[*cfg["collision_links"], "panda_link8"])
    with pytest.raises(ValueError, match=r"collision link 'panda_link8' has no <collision> geometry in panda.urdf"):
        load_robot(path)


def test_configured_joint_missing_from_urdf(tmp_path):
    cfg = yaml.safe_load((conf_dir() / "robot" / "panda.yaml").read_text())
    path = _panda_yaml(tmp_path, joints=[*cfg["joints"][:6], "panda_joint99"])
    with pytest.raises(ValueError, match=r"joint 'panda_joint99' is not in panda.urdf; its joints are \[.*'panda_joint1'"):
        load_robot(path)


def test_unknown_config_key_names_valid_keys(tmp_path):
    with pytest.raises(ValueError, match=r"invalid robot config.*joint_limitz.*Valid keys: name, urdf"):
        load_robot(_panda_yaml(tmp_path, joint_limitz=[0, 1]))


def test_limits_wider_than_urdf_are_refused(tmp_path):
    cfg = yaml.safe_load((conf_dir() / "robot" / "panda.yaml").read_text())
    path = _panda_yaml(tmp_path, upper=[3.5, *cfg["upper"][1:]])
    with pytest.raises(ValueError, match=r"limits \[-2.8973, 3.5\] of 'panda_joint1' exceed the URDF's"):
        load_robot(path)


@pytest.mark.parametrize("shape", [(2, 6), (2, 8), (7,)])
def test_q_of_the_wrong_width(robots, shape):
    robot = robots["panda"]
    q = torch.zeros(shape, dtype=robot.dtype)
    with pytest.raises(ValueError, match=r"q must have shape \(B, 7\) for panda's joints .* got \(" + ", ".join(map(str, shape))):
        robot.fk(q)
    with pytest.raises(ValueError, match=r"q must have shape \(B, 7\)"):
        robot.transform_points(q)


def test_q_of_another_dtype(robots):
    with pytest.raises(TypeError, match=r"q has dtype torch.float32 but the robot is torch.float64"):
        robots["panda"].fk(torch.zeros(1, 7))
