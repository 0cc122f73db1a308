"""A user's own config folders (`SAMP_CONFIG_PATH`) beside samp's, and where output goes by default.

The user's folder is written here, outside the repository, as a user would: a robot, a dataset spec and an
experiment of their own, and one file that shadows a packaged one. The oracle is the packaged tree itself:
everything of it stays visible, the user's files are added, and the shadowing file wins and is named.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture
def user_conf(tmp_path, monkeypatch):
    conf = tmp_path / "myconf"
    (conf / "robot").mkdir(parents=True)
    (conf / "experiment").mkdir()
    (conf / "dataset").mkdir()
    panda = (REPO / "conf" / "robot" / "panda.yaml").read_text().replace("name: panda", "name: mypanda")
    (conf / "robot" / "mypanda.yaml").write_text(panda)
    (conf / "experiment" / "mine.yaml").write_text(
        "# @package _global_\n# My quick experiment on my Panda.\ndefaults:\n  - quickstart\n  - override /robot: mypanda\n")
    smoke = (REPO / "conf" / "dataset" / "smoke.yaml").read_text()
    (conf / "dataset" / "smoke.yaml").write_text(smoke.replace("trajectories_per_scene: 4", "trajectories_per_scene: 5"))
    monkeypatch.setenv("SAMP_CONFIG_PATH", str(conf))
    monkeypatch.setenv("SAMP_CACHE_DIR", str(tmp_path / "cache"))
    return conf


def test_the_user_folder_is_added_in_front_of_samps_own(user_conf, capsys):
    from samp import paths
    from samp.config_overlay import visible_files

    paths._said.clear()
    merged = paths.conf_dir()
    own = visible_files(REPO / "conf")
    assert set(own) <= set(visible_files(merged)), "a packaged config went missing from the merged view"
    assert (merged / "robot" / "mypanda.yaml").resolve() == (user_conf / "robot" / "mypanda.yaml").resolve()
    assert (merged / "dataset" / "smoke.yaml").resolve() == (user_conf / "dataset" / "smoke.yaml").resolve()
    assert (merged / "dataset" / "quickstart.yaml").resolve() == (REPO / "conf" / "dataset" / "quickstart.yaml").resolve()
    said = capsys.readouterr().err
    assert said.count("dataset/smoke.yaml") == 1 and str(user_conf) in said, said
    paths.conf_dir()
    assert "smoke.yaml" not in capsys.readouterr().err, "shadowing must be said once per process"


def test_user_robot_spec_and_experiment_compose(user_conf):
    from samp.cli import compose
    from samp.data.spec import load_spec
    from samp.robot import available_robots

    assert "mypanda" in available_robots() and "panda" in available_robots()
    assert load_spec("smoke").trajectories_per_scene == 5  # the user's spec shadows the packaged one
    cfg = compose("train", ["experiment=mine"])
    assert cfg.robot.name == "mypanda"


def test_train_help_lists_the_users_experiments_beside_ours(user_conf):
    out = subprocess.run([sys.executable, "-m", "samp.train", "--help"], capture_output=True, text=True,
                         env={**os.environ}, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = {line.split()[0]: line for line in out.stdout.splitlines() if line.startswith("  ") and line.split()}
    assert "[yours]" in lines["mine"] and "quickstart" in lines and "[yours]" not in lines["quickstart"]


def test_a_missing_config_folder_is_a_clear_error(tmp_path, monkeypatch):
    from samp import paths

    monkeypatch.setenv("SAMP_CONFIG_PATH", str(tmp_path / "nope"))
    with pytest.raises(FileNotFoundError, match="SAMP_CONFIG_PATH names .*nope.* not a folder"):
        paths.conf_dir()


def test_output_defaults_follow_samp_home(tmp_path, monkeypatch):
    from samp.data.registry import datasets_root
    from samp.paths import project_dir, runs_root

    for var in ("SAMP_RUNS_DIR", "SAMP_DATASETS_DIR"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setenv("SAMP_HOME", str(tmp_path / "proj"))
    assert project_dir() == tmp_path / "proj" and (tmp_path / "proj").is_dir()
    assert runs_root() == tmp_path / "proj" / "runs" and datasets_root() == tmp_path / "proj" / "datasets"
    monkeypatch.delenv("SAMP_HOME")
    assert project_dir() == REPO  # a clone keeps its own runs/ and datasets/
