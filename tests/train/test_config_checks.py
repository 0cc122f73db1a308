"""Config errors before work (issue 21): a wrong type or an out-of-range value is refused when the config
is composed, naming the key, the value and what is allowed, before any run folder is made or any
prerequisite (dataset, robot SDF) is built."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from samp.train import compose_train_config

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


@pytest.mark.parametrize("override, message", [
    ("datamodule.batch_size=abc", "config key datamodule.batch_size='abc': samp.data.module.TrajectoryDataModule takes "
                                  "int for 'batch_size', got a str"),
    ("datamodule.n_e=-1", "config key datamodule.n_e=-1 is out of range: n_e must be in [2, 256]"),
    ("datamodule.batch_size=0", "config key datamodule.batch_size=0 is out of range: batch_size must be in [1, 65536]"),
    ("trainer.max_steps=1.5", "config key trainer.max_steps=1.5: pytorch_lightning.Trainer takes int"),
    ("name=..", "experiment name (name=...), the folder its runs go to, '..' is not a plain folder name"),
    ("name=a/b", "'a/b' is not a plain folder name: it holds a path separator"),
    ("seed=abc", "invalid top-level config value for key 'seed': Value 'abc' of type 'str' could not be converted"),
])
def test_bad_values_are_refused_when_composed(override, message):
    with pytest.raises(ValueError) as err:
        compose_train_config(["experiment=quickstart", override])
    assert message in str(err.value), str(err.value)


def test_good_values_of_the_same_keys_compose():
    cfg = compose_train_config(["experiment=quickstart", "datamodule.batch_size=7", "datamodule.n_e=12",
                                "trainer.max_steps=3"])
    assert (cfg.datamodule.batch_size, cfg.datamodule.n_e, cfg.trainer.max_steps) == (7, 12, 3)


@pytest.mark.parametrize("override", ["datamodule.batch_size=abc", "datamodule.n_e=-1"])
def test_the_cli_refuses_before_any_folder_or_prerequisite(override, tmp_path):
    runs, datasets = tmp_path / "runs", tmp_path / "datasets"
    env = {**os.environ, "SAMP_RUNS_DIR": str(runs), "SAMP_DATASETS_DIR": str(datasets), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-m", "samp.train", "experiment=quickstart", override,
                          "build_missing.dataset=true", "build_missing.robot_sdf=true"],
                         capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 2, out.stdout[-2000:] + out.stderr[-2000:]
    key, _, value = override.partition("=")
    assert f"config key {key}={value if value.startswith('-') else repr(value)}" in out.stderr, out.stderr
    assert not runs.exists() or not any(runs.rglob("*")), "a run folder was made"
    assert not datasets.exists() or not any(datasets.rglob("*")), "a prerequisite was built"
