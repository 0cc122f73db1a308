"""A run stopped by SIGTERM mid-training is marked interrupted; `samp.train resume=RUN_DIR` finishes it in
the same folder, metrics.csv and the MLflow run continuing. Lineage fields of the finished run."""

from __future__ import annotations

import csv
import json
import os
import signal
import threading

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

STEPS = 160


@pytest.fixture(scope="module")
def resumed(tmp_path_factory, cli, tiny_sdf, stop_at_first_checkpoint):
    """(runs folder, run folder, the killed process's output, run.json after the kill, the resume's output)."""
    runs = tmp_path_factory.mktemp("resume_runs")
    args = ["+experiment=robot_sdf_panda", f"trainer.max_steps={STEPS}", "callbacks.model_checkpoint.every_n_train_steps=10",
            *tiny_sdf]
    tracked = {"SAMP_TRACKING_URI": None}  # into the local store, the default (the suite turns it off)
    proc = cli("samp.train", args, runs, popen=True, prelude=stop_at_first_checkpoint, env=tracked)
    ckpts = runs / "robot_sdf_panda"
    output: list[str] = []
    reader = threading.Thread(target=lambda: output.append(proc.stdout.read()), daemon=True)  # keeps the pipe open
    reader.start()
    try:
        _, status = os.waitpid(proc.pid, os.WUNTRACED)  # until it stops itself after its first last.ckpt
        if os.WIFSTOPPED(status):
            assert list(ckpts.glob("*/checkpoints/last.ckpt")), "stopped without a last.ckpt"
            proc.send_signal(signal.SIGTERM)  # delivered when it continues, mid-training as from a scheduler
            proc.send_signal(signal.SIGCONT)
        proc.wait(timeout=300)
        reader.join(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
    killed = "".join(output)
    assert os.WIFSTOPPED(status), "the run ended before its first checkpoint: " + killed[-2000:]
    assert proc.returncode != 0, killed[-2000:]
    (folder,) = ckpts.iterdir()
    after_kill = json.loads((folder / "run.json").read_text())
    again = cli("samp.train", [f"resume={folder}"], runs, env=tracked)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr[-3000:]
    return runs, folder, killed, after_kill, again


def test_sigterm_marks_the_run_interrupted(resumed):
    _, _, killed, after_kill, _ = resumed
    assert after_kill["status"] == "interrupted" and after_kill["end"], after_kill["status"]
    assert after_kill.get("steps") is None, "the killed run must not look finished"


def test_resume_finishes_the_same_folder(resumed):
    runs, folder, _, _, again = resumed
    assert f"run folder: {folder} (resuming from last.ckpt)" in again.stdout
    assert [p.name for p in (runs / "robot_sdf_panda").iterdir()] == [folder.name], "resuming made a new folder"
    record = json.loads((folder / "run.json").read_text())
    assert record["status"] == "completed" and record["steps"] == STEPS and len(record["starts"]) == 2
    assert record["overrides"][0] == "+experiment=robot_sdf_panda", "the recorded overrides were not reused"


def test_metrics_csv_continues_across_the_resume(resumed):
    _, folder, _, after_kill, _ = resumed
    rows = list(csv.DictReader(open(folder / "metrics.csv")))
    steps = [int(r["step"]) for r in rows if r.get("train/loss")]
    assert steps[0] < 10 and steps[-1] >= STEPS - 5, f"rows from the first start were lost: steps {steps[:3]}..{steps[-3:]}"
    assert steps == sorted(set(steps)), f"train/loss steps repeat or go back: {steps}"
    assert all(b - a == 5 for a, b in zip(steps, steps[1:])), f"a gap in the logged steps: {steps}"


def test_lineage_fields_are_filled(resumed):
    from samp.provenance import code_version

    _, folder, _, _, _ = resumed
    record = json.loads((folder / "run.json").read_text())
    assert len(record["dataset_id"]) == 12 and len(record["robot_sdf_artifact_id"]) == 12
    assert record["code_version"] == json.loads(json.dumps(code_version()))
    assert record["packages"]["torch"] and record["packages"]["pytorch-lightning"] and record["packages"]["python"]
    assert record["seed"] == 0 and record["config"]["seed"] == 0 and record["experiment"] == "robot_sdf_panda"
    assert record["config"]["trainer"]["max_steps"] == STEPS and record["config"]["run_dir"] == str(folder)
    assert record["host"] and record["fit_time_s"] > 0 and record["epochs"] == STEPS // 20


def test_mlflow_records_params_metrics_and_lineage_tags_in_sqlite(resumed):
    from mlflow.tracking import MlflowClient

    runs, folder, _, _, _ = resumed
    record = json.loads((folder / "run.json").read_text())
    uri = record["loggers"]["mlflow"]["tracking_uri"]
    assert uri == f"sqlite:///{runs.resolve()}/mlflow.db" and (runs / "mlflow.db").is_file()
    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("robot_sdf_panda")
    found = client.search_runs([experiment.experiment_id])
    assert len(found) == 1, "the resumed run must continue the same MLflow run"
    run = found[0]
    assert run.info.run_id == record["loggers"]["mlflow"]["run_id"]
    params = run.data.params  # the resolved config, as dotted keys
    assert params["robot.name"] == "panda" and params["trainer.max_steps"] == str(STEPS) and params["seed"] == "0"
    tags = run.data.tags
    assert tags["samp.dataset_id"] == record["dataset_id"] and tags["samp.seed"] == "0"
    assert tags["samp.git_commit"] == str(record["code_version"]["git_commit"])
    assert tags["samp.robot_sdf_artifact_id"] == record["robot_sdf_artifact_id"]
    history = [m.step for m in client.get_metric_history(run.info.run_id, "train/loss")]
    assert min(history) < 10 and max(history) >= STEPS - 5, history
    final = client.get_metric_history(run.info.run_id, "eval/whole_robot/mae_all_mm")
    assert [m.value for m in final] == [pytest.approx(record["metrics"]["eval/whole_robot/mae_all_mm"])]


def test_resume_without_a_checkpoint_is_refused_and_changes_nothing(resumed, cli, tmp_path):
    """A run folder with a run.json but no checkpoints/last.ckpt (stopped before its first checkpoint):
    `resume=` exits non-zero saying so and how to go on, and leaves the folder as it was."""
    import shutil

    _, folder, _, _, _ = resumed
    copy = tmp_path / "robot_sdf_panda" / folder.name
    copy.mkdir(parents=True)
    shutil.copy2(folder / "run.json", copy / "run.json")
    before = (copy / "run.json").read_text()
    again = cli("samp.train", [f"resume={copy}"], tmp_path)
    assert again.returncode != 0, again.stdout[-2000:]
    message = again.stdout + again.stderr
    assert f"cannot resume {copy}" in message and "has no last.ckpt" in message and "start it again" in message, \
        message[-2000:]
    assert (copy / "run.json").read_text() == before and sorted(p.name for p in copy.iterdir()) == ["run.json"]
