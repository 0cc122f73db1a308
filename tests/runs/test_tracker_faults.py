"""A tracking store that fails never fails the run (issue 52), against a real MLflow sqlite store:

* locked by another process (a `BEGIN EXCLUSIVE` transaction held from a second sqlite3 connection) while a
  trained run logs its tags, files and final metrics: one warning line, no traceback, run.json `completed`;
* corrupt (`mlflow.db` overwritten with other bytes) when a run starts: one warning line, the run untracked.

The retries are cut to one try: MLflow itself waits 20 s for a sqlite lock on each call, which is the wait
these tests cost."""

from __future__ import annotations

import json
import sqlite3

import pytest
from omegaconf import OmegaConf

from samp.names import RUN_JSON, TRACKING_DB
from samp.runs import RunFolder


def _cfg(runs) -> object:
    return OmegaConf.create({"name": "t", "tracking": {"uri": None, "recording": False},
                             "paths": {"runs_dir": str(runs), "datasets_dir": str(runs)}})


@pytest.fixture
def tracked(monkeypatch):
    """The local store under the runs folder (the suite turns tracking off), one try per store call."""
    import samp.tracking_faults

    monkeypatch.delenv("SAMP_TRACKING_URI", raising=False)
    monkeypatch.setattr(samp.tracking_faults, "ATTEMPTS", 1)


def _warnings(err: str) -> list[str]:
    assert "Traceback" not in err, err
    return [line for line in err.splitlines() if line.startswith("warning:")]


def test_a_store_locked_after_training_leaves_the_run_completed(tmp_path, tracked, capsys):
    from samp.runs.loggers import finish_loggers
    from samp.runs.tracker_guard import start_tracking

    runs = tmp_path / "runs"
    folder = RunFolder.create(runs, "t")
    with folder.record(experiment="t", seed=0, overrides=[], run_dir=str(folder.path), config={}):
        tracker = start_tracking(_cfg(runs), folder)
        assert tracker is not None, capsys.readouterr()
        tracker.log_metrics({"train/loss": 1.0}, step=0)  # tracked while the store is free
        lock = sqlite3.connect(runs / TRACKING_DB, isolation_level=None)
        lock.execute("BEGIN EXCLUSIVE")  # another process holds the store for longer than the retries
        try:
            record = folder.update(steps=1, metrics={"train/loss": 1.0})
            finish_loggers([tracker], record, {"eval/success": 0.5}, step=1)
        finally:
            lock.execute("ROLLBACK")
            lock.close()
    record = json.loads((folder.path / RUN_JSON).read_text())
    assert record["status"] == "completed", record.get("error")
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 1 and "database is locked" in lines[0] and "tracking is off" in lines[0], lines
    assert str(folder.path) in lines[0], lines


def test_a_corrupt_store_at_the_start_leaves_the_run_untracked(tmp_path, tracked, capsys):
    from samp.runs.tracker_guard import start_tracking

    runs = tmp_path / "runs"
    runs.mkdir()
    (runs / TRACKING_DB).write_bytes(b"not a database " * 512)
    folder = RunFolder.create(runs, "t")
    assert start_tracking(_cfg(runs), folder) is None
    lines = _warnings(capsys.readouterr().err)
    assert len(lines) == 1 and "file is not a database" in lines[0] and "tracking is off" in lines[0], lines
    assert (runs / TRACKING_DB).read_bytes() == b"not a database " * 512, "the store was changed"
