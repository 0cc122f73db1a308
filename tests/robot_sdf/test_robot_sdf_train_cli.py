"""`python -m samp.train +experiment=robot_sdf_panda` end to end on tiny data, its run folder, and the
errors for bad input; the run-folder record on failure and interruption."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

RERUN = Path(sys.executable).parent / "rerun"
TINY = ["robot_sdf_samples=tiny", "robot_sdf_eval=tiny", "trainer.max_steps=120", "datamodule.steps_per_epoch=40",
        "datamodule.near_per_step=256", "datamodule.uniform_per_step=128", "trainer.enable_progress_bar=false",
        "trainer.log_every_n_steps=5", "robot_sdf_eval.timing_batches=[1]", "model.encoding.levels=8",
        "model.encoding.log2_table_size=14", "model.encoding.finest=256", "system.optimizer.lr=0.01"]


def _train(tmp_path: Path, *args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "SAMP_RUNS_DIR": str(tmp_path / "runs"), "SAMP_DATASETS_DIR": str(tmp_path / "datasets"),
           "RERUN_ANALYTICS": "0"}
    return subprocess.run([sys.executable, "-m", "samp.train", *args], capture_output=True, text=True, timeout=600, env=env)


@pytest.fixture(scope="module")
def tiny_run(tmp_path_factory, panda):
    """One tiny training run through the CLI (panda: robot points cached for the subprocess)."""
    tmp = tmp_path_factory.mktemp("train_cli")
    proc = _train(tmp, "+experiment=robot_sdf_panda", *TINY)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = list((tmp / "runs" / "robot_sdf_panda").iterdir())
    assert len(runs) == 1
    return runs[0]


def test_training_improves_the_loss_and_records_the_run(tiny_run, panda):
    rows = list(csv.DictReader(open(tiny_run / "metrics.csv")))
    losses = [float(r["train/loss"]) for r in rows if r.get("train/loss")]
    assert len(losses) >= 10 and losses[-1] < 0.2 * losses[0], f"train/loss did not fall: {losses[0]} -> {losses[-1]}"
    record = json.loads((tiny_run / "run.json").read_text())
    assert record["status"] == "completed" and record["end"] and record["steps"] == 120
    assert record["dataset_id"] and len(record["robot_sdf_artifact_id"]) == 12
    assert {"git_commit", "git_dirty"} <= set(record["code_version"]) and record["packages"]["torch"]
    assert record["host"] and record["seed"] == 0
    assert record["metrics"]["eval/whole_robot/mae_all_mm"] > 0 and record["metrics"]["train_time_s"] > 0
    assert (tiny_run / ".hydra" / "config.yaml").is_file() and (tiny_run / "checkpoints" / "last.ckpt").is_file()
    for name in ("robot_sdf.pt", "robot_sdf_table.md", "robot_sdf_table.json", "robot_sdf.rrd"):
        assert (tiny_run / name).is_file(), name
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(tiny_run / "robot_sdf.rrd")], capture_output=True, text=True,
                            timeout=120)
    assert verify.returncode == 0, verify.stderr


def test_run_folder_and_checkpoint_load_as_the_same_robot_sdf(tiny_run, panda):
    from samp.robot_sdf import load_robot_sdf

    a = load_robot_sdf(tiny_run, panda)
    b = load_robot_sdf(tiny_run / "checkpoints" / "last.ckpt", panda)
    assert a.meta["dataset_id"] == b.meta["dataset_id"] == json.loads((tiny_run / "run.json").read_text())["dataset_id"]
    q = panda.home[None].float()
    points = panda.transform_points(q)
    with torch.no_grad():
        torch.testing.assert_close(a.query(points, q), b.query(points, q), atol=0, rtol=0)
    with pytest.raises(ValueError, match="trained for robot 'panda'"):
        load_robot_sdf(tiny_run, "iiwa")


@pytest.mark.parametrize("args, message", [
    (["+experiment=robot_sdf_panda", "+sed=1"], "unknown top-level config key(s) ['sed']; valid keys:"),
    (["+experiment=robot_sdf_panda", "trainer.max_step=3"], "valid keys there: _target_, accelerator"),
    (["+experiment=robot_sdf_panda", "+system.optimizer.lrr=1"], "unknown key(s) ['lrr'] for torch.optim.Adam; valid keys:"),
    (["+experiment=robot_sdf_nope"], "Could not find 'experiment/robot_sdf_nope'"),
    (["seed=1"], "the config sets no `name`; pick an experiment"),
])
def test_bad_arguments_give_one_line_errors(tmp_path, args, message):
    proc = _train(tmp_path, *args)
    assert proc.returncode == 2 and message in proc.stderr, proc.stderr[-2000:]
    assert "Traceback" not in proc.stderr
    assert not (tmp_path / "runs").exists(), "a run folder was created for a config that does not compose"


def test_run_record_marks_failures_and_interruptions(tmp_path):
    from samp.runs import RunFolder

    folder = RunFolder.create(tmp_path, "exp")
    with pytest.raises(RuntimeError):
        with folder.record(seed=3):
            raise RuntimeError("boom")
    record = folder.read()
    assert record["status"] == "failed" and "boom" in record["error"] and record["seed"] == 3 and record["end"]
    with pytest.raises(KeyboardInterrupt):
        with folder.record():
            raise KeyboardInterrupt
    assert folder.read()["status"] == "interrupted" and len(folder.read()["starts"]) == 2
    with folder.record():
        pass
    assert folder.read()["status"] == "completed"
    assert RunFolder.create(tmp_path, "exp").path != folder.path
