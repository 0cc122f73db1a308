"""Sweeps over experiments take the keys an experiment brings as a single run does (samp.train.sweep):
composition only, no training."""

from __future__ import annotations

import json

import pytest


def test_keys_an_experiment_brings_are_handed_to_hydra_forced_and_checked_first():
    from samp.train.sweep import _keys_of_swept_experiments

    argv = ["sweep=anchor_size", "datamodule.dataset=smoke", "callbacks.eval.problems=2", "trainer.max_epochs=1",
            "seed=0"]
    got = _keys_of_swept_experiments(argv)
    # datamodule and the eval callback exist only once an experiment is chosen; trainer and seed always do
    assert got == ["sweep=anchor_size", "++datamodule.dataset=smoke", "++callbacks.eval.problems=2",
                   "trainer.max_epochs=1", "seed=0"], got
    single = ["experiment=samp_n40", "seed=0,1", "datamodule.dataset=smoke"]  # experiment fixed: as given
    assert _keys_of_swept_experiments(single) == single


def test_a_typo_in_a_sweep_over_experiments_is_named_before_anything_runs(capsys):
    from samp.train.sweep import multirun

    assert multirun(["experiment=samp_n40,samp_n70", "datamodule.datset=smoke"]) == 2
    err = capsys.readouterr().err
    assert "unknown config key 'datamodule.datset'" in err and "dataset" in err, err


def test_a_member_recorded_with_forced_keys_is_the_same_member(tmp_path):
    """Run again, a member whose run.json holds `++datamodule.dataset=smoke` (or the plain spelling) is
    skipped, not refused as completed with other overrides."""
    from samp.train.sweep import member_state

    folder = tmp_path / "experiment=samp_n40"
    folder.mkdir()
    (folder / "run.json").write_text(json.dumps({"status": "completed", "overrides": [
        "experiment=samp_n40", "++datamodule.dataset=smoke"]}))
    assert member_state(folder, ["experiment=samp_n40", "datamodule.dataset=smoke"]) == "skip"
    assert member_state(folder, ["experiment=samp_n40", "++datamodule.dataset=smoke"]) == "skip"
    with pytest.raises(ValueError, match="completed with overrides"):
        member_state(folder, ["experiment=samp_n40", "datamodule.dataset=other"])


def test_cfg_job_on_a_sweep_prints_its_first_member(capsys):
    from samp.train.cli import main

    assert main(["-m", "sweep=anchor_size", "datamodule.dataset=smoke", "--cfg", "job"]) == 0
    out = capsys.readouterr().out
    assert "name: samp_n40" in out and "dataset: smoke" in out, out[:500]


def test_every_member_state(tmp_path):
    """What a sweep member does with the folder it finds, state by state: nothing there -> new; completed with
    the same overrides -> skip (others: refused); still running here (a live pid on this host) -> refused; stopped
    (interrupted, failed, or "running" with a dead pid) after a checkpoint -> resume; stopped before any
    checkpoint -> new, the earlier attempt's run.json and metrics.csv kept under numbered names."""
    import os
    import subprocess
    import sys

    from samp.train.sweep import member_state

    overrides = ["experiment=exp", "seed=0"]
    folder = tmp_path / "seed=0"
    folder.mkdir()
    assert member_state(folder, overrides) == "new"

    def record(**fields):
        (folder / "run.json").write_text(json.dumps({"overrides": overrides, **fields}))

    record(status="completed")
    assert member_state(folder, overrides) == "skip"
    with pytest.raises(ValueError, match="completed with overrides"):
        member_state(folder, ["experiment=exp", "seed=1"])

    alive = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        record(status="running", host=os.uname().nodename, pid=alive.pid)
        with pytest.raises(ValueError, match=f"still running \\(pid {alive.pid}\\)"):
            member_state(folder, overrides)
    finally:
        alive.kill()
        alive.wait()
    (folder / "checkpoints").mkdir()
    (folder / "checkpoints" / "last.ckpt").write_bytes(b"weights")
    for status, extra in [("running", {"host": os.uname().nodename, "pid": alive.pid}), ("interrupted", {}),
                          ("failed", {})]:
        record(status=status, **extra)
        assert member_state(folder, overrides) == "resume", status

    (folder / "checkpoints" / "last.ckpt").unlink()
    for attempt in (1, 2):
        record(status="interrupted", attempt=attempt)
        (folder / "metrics.csv").write_text(f"step,attempt\n0,{attempt}\n")
        assert member_state(folder, overrides) == "new"
        assert not (folder / "run.json").exists() and not (folder / "metrics.csv").exists()
        assert json.loads((folder / f"run.attempt-{attempt}.json").read_text())["attempt"] == attempt
        assert (folder / f"metrics.attempt-{attempt}.csv").read_text().endswith(f"0,{attempt}\n")
