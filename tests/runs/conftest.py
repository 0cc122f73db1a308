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
    """cli(module, args, runs_dir, timeout=300, popen=False, prelude=None, env=None): `python -m MODULE ARGS` with
    its runs in `runs_dir` and one datasets folder for the whole session (the tiny SDF samples are made once);
    `prelude`: Python code run in that process first (e.g. `STOP_AT_FIRST_CHECKPOINT`); `env`: more
    environment variables (a value None removes one: `env={"SAMP_TRACKING_URI": None}` tracks into the runs
    folder's local store, which the suite otherwise turns off)."""
    datasets = tmp_path_factory.mktemp("runs_datasets")

    def run(module: str, args: list[str], runs_dir: Path, timeout: int = 300, popen: bool = False,
            prelude: str | None = None, env: dict | None = None):
        extra = env or {}
        env = {**{k: v for k, v in os.environ.items() if k not in extra}, "SAMP_RUNS_DIR": str(runs_dir),
               "SAMP_DATASETS_DIR": str(datasets), "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1",
               **{k: v for k, v in extra.items() if v is not None}}
        cmd = [sys.executable, "-m", module, *args]
        if prelude is not None:
            code = f"{prelude}\nimport runpy, sys\nsys.argv = [{module!r}, *sys.argv[1:]]\n" \
                   f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)\n"
            cmd = [sys.executable, "-c", code, *args]
        if popen:
            return subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
        return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, env=env)

    return run


# Run in the training process (`cli(..., prelude=STOP_AT_FIRST_CHECKPOINT)`): a callback makes the process
# stop itself (SIGSTOP) at the start of the first training batch after a `last.ckpt` exists, so a test can
# signal it at a known point between steps instead of polling for the file against a wall-clock deadline
# (which failed on a loaded machine, and could miss a run that finished first).
STOP_AT_FIRST_CHECKPOINT = """
import os, signal
from pathlib import Path
import pytorch_lightning as pl

class _StopAfterFirstCheckpoint(pl.Callback):
    stopped = False

    def on_train_batch_start(self, trainer, *args):
        ckpt = trainer.checkpoint_callback
        if not self.stopped and ckpt is not None and ckpt.dirpath and (Path(ckpt.dirpath) / "last.ckpt").exists():
            type(self).stopped = True
            os.kill(os.getpid(), signal.SIGSTOP)

_init = pl.Trainer.__init__

def _init_with_stop(self, *args, callbacks=None, **kwargs):
    _init(self, *args, callbacks=[*(callbacks or []), _StopAfterFirstCheckpoint()], **kwargs)

pl.Trainer.__init__ = _init_with_stop
"""


@pytest.fixture(scope="session")
def stop_at_first_checkpoint() -> str:
    return STOP_AT_FIRST_CHECKPOINT
