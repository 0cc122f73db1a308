"""The demo pipeline end to end through the real CLI (`make demo` runs the same command at full size):
`python -m samp.train +experiment=quickstart` on a fresh registry builds the dataset (the `smoke` spec) and
the robot SDF (tiny settings), trains the policy briefly, evaluates it beside the expert and the straight
line, and leaves every artifact a user is pointed to."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def demo(tmp_path_factory, _isolated_cache):
    tmp = tmp_path_factory.mktemp("demo")
    env = {**os.environ, "SAMP_RUNS_DIR": str(tmp / "runs"), "SAMP_DATASETS_DIR": str(tmp / "datasets")}
    cmd = [sys.executable, "-m", "samp.train", "+experiment=quickstart", "datamodule.dataset=smoke",
           "datamodule.n_e=16", "datamodule.val_samples=50", "trainer.max_epochs=1",
           "+trainer.limit_train_batches=4", "trainer.enable_progress_bar=false", "system.eval_problems=2",
           "system.build_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    (run,) = (tmp / "runs" / "quickstart").iterdir()
    return tmp, run, out.stdout


def test_the_dataset_was_built_and_verifies(demo):
    from samp.data.registry import resolve_ref, verify_dataset

    tmp, run, _ = demo
    folder = resolve_ref("smoke", tmp / "datasets")
    assert verify_dataset(folder) == [], "the generated dataset does not verify"
    record = json.loads((run / "run.json").read_text())
    assert record["dataset_id"] == f"smoke@{folder.name}"


def test_run_json_is_complete(demo):
    tmp, run, _ = demo
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "completed"
    for key in ("dataset_id", "robot_sdf_artifact_id", "code_version", "seed", "config", "start", "end", "steps"):
        assert record.get(key) not in (None, ""), f"run.json has no {key!r}: {sorted(record)}"
    assert record["steps"] == 4
    (sdf_run,) = (tmp / "runs" / "robot_sdf_panda_quick").iterdir()  # built on demand, in its own run folder
    assert json.loads((sdf_run / "run.json").read_text())["status"] == "completed"
    for planner in ("samp", "expert", "straight"):
        for split in ("train", "heldout"):
            assert f"eval/{planner}/{split}/success_rate" in record["metrics"], (planner, split, sorted(record["metrics"]))


def test_metrics_recording_and_plot_are_there(demo):
    _, run, stdout = demo
    report = json.loads((run / "eval" / "metrics.json").read_text())
    for key in ("metrics", "expert", "straight"):
        assert set(report[key]) >= {"train", "heldout"}, (key, sorted(report[key]))
        assert report[key]["train"]["problems"] == 2
    assert report["expert"]["train"]["success_rate"] == 1.0  # the expert's own trajectories
    assert (run / "plots" / "summary.png").stat().st_size > 10_000
    recording = run / "eval" / "recording.rrd"
    rerun = Path(sys.executable).with_name("rerun")
    rerun = str(rerun) if rerun.is_file() else shutil.which("rerun")
    assert rerun, "the rerun CLI (rerun-sdk) is not installed next to this Python"
    check = subprocess.run([rerun, "rrd", "verify", str(recording)], capture_output=True, text=True, timeout=300)
    assert check.returncode == 0, check.stderr[-2000:]
    # The run ends by printing the table and where its files are.
    assert "| samp | heldout |" in stdout and "| straight | heldout |" in stdout
    assert f"recording: {recording}" in stdout and f"plots: {run / 'plots' / 'summary.png'}" in stdout
