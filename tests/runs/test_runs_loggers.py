"""The loggers a run can have (conf/logger/, lists of them) and where it is tracked: the CSV log against
Lightning's own CSVLogger as the oracle of its format, continued across a resume; the tracking URI; the local
store's artifacts beside the runs. (What the store holds: test_runs_tracking.py.)"""

from __future__ import annotations

import csv
from pathlib import Path

import pytest

# Rows as a training logs them: a key that appears later (a wider header), steps not every row, a tensor.
CALLS = [({"train/loss": 1.5, "epoch": 0.0}, 0), ({"train/loss": 1.25, "epoch": 0.0}, 5),
         ({"val/loss": 2.0, "epoch": 0.0}, 9), ({"train/loss": 1.0, "lr-AdamW": 0.001, "epoch": 1.0}, 10),
         ({"eval/samp/val/success_rate": 0.5}, 12)]


def _log(logger, calls) -> None:
    import torch

    for metrics, step in calls:
        logger.log_metrics({k: torch.tensor(v) if k == "train/loss" else v for k, v in metrics.items()}, step=step)
        logger.save()
    logger.finalize("success")


def test_metrics_csv_has_the_format_of_lightnings_csv_logger(tmp_path):
    """The same calls give the same file as Lightning's CSVLogger (what samp.runs was written against)."""
    from pytorch_lightning.loggers import CSVLogger

    from samp.runs.loggers import RunCSVLogger

    _log(RunCSVLogger(str(tmp_path / "ours")), CALLS)
    _log(CSVLogger(str(tmp_path / "lightning"), name="", version=""), CALLS)
    ours, theirs = (tmp_path / "ours" / "metrics.csv").read_text(), (tmp_path / "lightning" / "metrics.csv").read_text()
    assert ours == theirs, f"expected\n{theirs}\ngot\n{ours}"


def test_metrics_csv_continues_when_the_run_folder_is_opened_again(tmp_path):
    """A resumed run's logger appends to the file (Lightning's would delete it), widening its header."""
    from samp.runs.loggers import RunCSVLogger

    _log(RunCSVLogger(str(tmp_path)), CALLS[:2])
    _log(RunCSVLogger(str(tmp_path)), CALLS[2:])
    rows = list(csv.DictReader((tmp_path / "metrics.csv").open()))
    assert [r["step"] for r in rows] == ["0", "5", "9", "10", "12"], rows
    assert [r["train/loss"] for r in rows] == ["1.5", "1.25", "", "1.0", ""]
    assert rows[-1]["eval/samp/val/success_rate"] == "0.5" and rows[0]["eval/samp/val/success_rate"] == ""


def test_rows_are_written_every_n_steps_without_save(tmp_path):
    from samp.runs.loggers import RunCSVLogger

    logger = RunCSVLogger(str(tmp_path), flush_logs_every_n_steps=5)
    logger.log_metrics({"train/loss": 1.0}, step=3)
    assert not (tmp_path / "metrics.csv").exists() and logger.has_rows()
    logger.log_metrics({"train/loss": 0.5}, step=4)  # (step + 1) % 5 == 0, as Lightning's
    assert len(list(csv.DictReader((tmp_path / "metrics.csv").open()))) == 2


@pytest.mark.parametrize("overrides, target", [
    (["logger=csv"], {"csv": "samp.runs.loggers.RunCSVLogger"}),
    (["logger=tensorboard"], {"csv": "samp.runs.loggers.RunCSVLogger",
                              "tensorboard": "samp.runs.loggers.tensorboard_logger"}),
    (["logger=[csv,tensorboard]"], {"csv": "samp.runs.loggers.RunCSVLogger",
                                    "tensorboard": "samp.runs.loggers.tensorboard_logger"}),
    (["logger=[tensorboard,wandb]"], {"csv": "samp.runs.loggers.RunCSVLogger",
                                      "tensorboard": "samp.runs.loggers.tensorboard_logger",
                                      "wandb": "samp.runs.loggers.wandb_logger"}),
    (["logger=mlflow"], {"csv": "samp.runs.loggers.RunCSVLogger"}),  # tracking is on anyway (`tracking.uri`)
])
def test_logger_options_and_lists_compose(overrides, target):
    from samp.train import compose_train_config

    cfg = compose_train_config(["+experiment=robot_sdf_panda", *overrides])
    assert {k: v["_target_"] for k, v in cfg.logger.items()} == target


def test_tensorboard_logger_writes_under_the_run_folder(tmp_path):
    from samp.runs.loggers import tensorboard_logger

    logger = tensorboard_logger(str(tmp_path))
    logger.log_metrics({"train/loss": 0.5}, step=1)
    logger.finalize("success")
    assert Path(logger.log_dir) == tmp_path / "tensorboard"
    assert list((tmp_path / "tensorboard").glob("events.out.tfevents.*")), list(tmp_path.rglob("*"))


@pytest.mark.parametrize("configured, env, want", [
    (None, None, "sqlite:///{runs}/mlflow.db"),
    (None, "http://mlflow.example:5000", "http://mlflow.example:5000"),
    ("sqlite:////data/team.db", "http://mlflow.example:5000", "sqlite:////data/team.db"),  # the config wins
    (None, "off", None),
    ("OFF", None, None),
    ("off", "http://mlflow.example:5000", None),
])
def test_the_tracking_uri(tmp_path, monkeypatch, configured, env, want):
    from samp.tracking import TRACKING_ENV, resolve_uri

    if env is None:
        monkeypatch.delenv(TRACKING_ENV, raising=False)
    else:
        monkeypatch.setenv(TRACKING_ENV, env)
    assert resolve_uri(configured, tmp_path) == (want.format(runs=tmp_path.resolve()) if want else None)


def test_the_train_config_has_tracking_on_by_default():
    from samp.train import compose_train_config

    cfg = compose_train_config(["+experiment=robot_sdf_panda"])
    assert cfg.tracking.uri is None and cfg.tracking.recording is True
    assert compose_train_config(["+experiment=robot_sdf_panda", "tracking.uri=off"]).tracking.uri == "off"


def test_copies_of_run_json_in_the_local_stores_artifacts_are_not_runs(tmp_path):
    """The local store keeps its artifacts in the runs folder (`mlflow-artifacts/`), run.json among them:
    scanning the runs folder finds the run once, in its own folder."""
    import shutil

    from samp.names import TRACKING_ARTIFACTS_DIR
    from samp.runs import RunFolder
    from samp.runs.registry import scan_runs

    run = RunFolder.create(tmp_path, "quickstart")
    run.update(status="completed", experiment="quickstart")
    copy = tmp_path / TRACKING_ARTIFACTS_DIR / "quickstart" / "0123abcd" / "artifacts"
    copy.mkdir(parents=True)
    shutil.copy2(run.path / "run.json", copy / "run.json")
    runs, damaged = scan_runs(tmp_path)
    assert [r.path for r in runs] == [run.path] and damaged == []
