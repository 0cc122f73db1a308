"""Shared pieces of the run-tracking tests: tiny robot SDF training settings (a few seconds a run) and a
runner for the real CLIs in subprocesses, with runs and datasets in tmp folders."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

# A robot SDF run small enough for a test: tiny samples, a small hash grid, a few dozen steps.
TINY_SDF = ["robot_sdf_samples=tiny", "robot_sdf_eval=tiny", "datamodule.steps_per_epoch=20",
            "datamodule.near_per_step=256", "datamodule.uniform_per_step=128", "trainer.enable_progress_bar=false",
            "trainer.log_every_n_steps=5", "robot_sdf_eval.timing_batches=[1]", "model.encoding.levels=8",
            "model.encoding.log2_table_size=14", "model.encoding.finest=256", "system.optimizer.lr=0.01"]


@pytest.fixture(scope="session")
def tiny_sdf() -> list[str]:
    return list(TINY_SDF)


@pytest.fixture(scope="session")
def cli(tmp_path_factory, _isolated_cache):
    """cli(module, args, runs_dir, timeout=300, popen=False): `python -m MODULE ARGS` with its runs in
    `runs_dir` and one datasets folder for the whole session (the tiny SDF samples are made once)."""
    datasets = tmp_path_factory.mktemp("runs_datasets")

    def run(module: str, args: list[str], runs_dir: Path, timeout: int = 300, popen: bool = False):
        env = {**os.environ, "SAMP_RUNS_DIR": str(runs_dir), "SAMP_DATASETS_DIR": str(datasets),
               "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1"}
        cmd = [sys.executable, "-m", module, *args]
        if popen:
            return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)

    return run
