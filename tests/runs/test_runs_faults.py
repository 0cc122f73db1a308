"""Run faults replayed with real training processes: a sweep member's folder (`experiment=mpinet,seed=1`) is
re-evaluated by `python -m samp.eval` given as run=PATH and bare (the fault: Hydra's "mismatched input '='"
and "unknown eval setting"); a training killed by SIGKILL shows `died` in `samp.runs ls` (the fault: it
stayed "running" forever); a typo in a filter key is refused with the closest key (the fault: "0 run(s)",
exit 0)."""

from __future__ import annotations

import json
import os
import signal
import threading

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

DATA = {"name": "rf_tiny", "robot": "panda", "seed": 7, "train_scenes": 1, "val_scenes": 1,
        "trajectories_per_scene": 3, "eval_problems_per_scene": 1, "generators": ["tabletop"], "resolutions": [16]}
# mpinet at its smallest: no robot SDF to build, a few steps (what is tested is the folder, not the policy)
TRAIN = ["+experiment=mpinet", "datamodule.dataset=rf_tiny", "datamodule.n_e=16", "trainer.max_steps=4",
         "trainer.max_epochs=-1", "trainer.enable_progress_bar=false", "datamodule.batch_size=8",
         "datamodule.val_samples=8", "evaluation.problems=1", "evaluation.benchmark=null",
         "model.robot_points=48", "model.obstacle_points=64", "model.target_points=16",
         "model.levels=[{centres:32,radius:0.15,neighbours:8,widths:[16,32]}]", "model.global_widths=[32,64]",
         "model.config_hidden=[16]", "model.decoder_hidden=[64]"]
EVAL = ["problems=1", "splits=[val]", "benchmark=null", "record=false", "overwrite=true"]


@pytest.fixture(scope="module")
def datasets(tmp_path_factory):
    from samp.data import generate

    root = tmp_path_factory.mktemp("rf_datasets")
    generate(DATA, root=root, progress=False)
    return root


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, cli, datasets):
    """(runs folder, the sweep's member folders) of a two-member sweep over the seed."""
    runs = tmp_path_factory.mktemp("rf_runs")
    folder = runs / "sweeps" / "seeds"
    proc = cli("samp.train", ["-m", *TRAIN, "seed=0,1", f"datamodule.root={datasets}", f"hydra.sweep.dir={folder}"],
               runs, timeout=900)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return runs, sorted(p for p in folder.iterdir() if p.is_dir())


@pytest.mark.parametrize("spelling", ["run=PATH", "PATH"])
def test_a_sweep_member_is_re_evaluated(sweep, cli, datasets, spelling):
    runs, members = sweep
    member = members[1]
    assert member.name == "experiment=mpinet,seed=1", [m.name for m in members]
    arg = spelling.replace("PATH", str(member))
    proc = cli("samp.eval", [arg, f"root={datasets}", *EVAL], runs, timeout=600)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    report = json.loads((member / "eval" / "metrics.json").read_text())
    assert report["planner"] == "mpinet" and report["metrics"]["val"]["problems"] == 1, report.get("metrics")


def test_a_training_killed_by_sigkill_shows_died(cli, datasets, tmp_path, stop_at_first_checkpoint):
    runs = tmp_path / "runs"
    args = [*TRAIN, "trainer.max_steps=200", "callbacks.model_checkpoint.every_n_train_steps=2",
            f"datamodule.root={datasets}"]
    proc = cli("samp.train", args, runs, popen=True, prelude=stop_at_first_checkpoint)
    reader = threading.Thread(target=proc.stdout.read, daemon=True)  # keeps the pipe drained
    reader.start()
    try:
        _, status = os.waitpid(proc.pid, os.WUNTRACED)  # until it stops itself mid-training
        assert os.WIFSTOPPED(status), "the run ended before its first checkpoint"
        (folder,) = (runs / "mpinet").iterdir()
        record = json.loads((folder / "run.json").read_text())
        assert record["status"] == "running" and record["pid"] == proc.pid and record["host"]
        listed = cli("samp.runs", ["ls", f"root={runs}"], runs)
        assert "| running |" in listed.stdout, listed.stdout  # alive (stopped): still running
        os.kill(proc.pid, signal.SIGKILL)  # no handler runs: run.json keeps saying running
        proc.wait(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert json.loads((folder / "run.json").read_text())["status"] == "running"
    listed = cli("samp.runs", ["ls", f"root={runs}"], runs)
    assert listed.returncode == 0 and "| died |" in listed.stdout and "| running |" not in listed.stdout, listed.stdout
    died = cli("samp.runs", ["ls", f"root={runs}", "status=died"], runs)
    assert "1 run(s)" in died.stdout, died.stdout


def test_a_typo_in_a_filter_key_is_refused(sweep, cli):
    runs, _ = sweep
    proc = cli("samp.runs", ["ls", f"root={runs}", "stauts=completed"], runs)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1, proc.stderr
    assert lines[0].startswith("error: unknown filter key 'stauts': no run here has it (did you mean 'status'?)")
    good = cli("samp.runs", ["ls", f"root={runs}", "status=completed"], runs)
    assert good.returncode == 0 and "2 run(s)" in good.stdout, good.stdout
