"""A run pulled from another machine is tracked in the puller's MLflow store, never at the path of the
pusher's local store that its run.json records (issue 53): a tracked run is pushed to a `file://` remote,
the run is pulled into another runs folder and its evaluation is logged through
`samp.tracking.track_evaluation`, the code path `python -m samp.eval run=RUN` takes. The stores are real
local MLflow stores, read back with MLflow's client."""

from __future__ import annotations

import json
import shutil
import uuid

import pytest

from samp.names import RUN_JSON, TRACKING_DB
from samp.runs.sharing import pull_run, push_run
from samp.tracking import TRACKING_ENV, client, experiment_id, track_evaluation

EXPERIMENT = "pulled"


def _store_runs(uri: str) -> list[str]:
    mlflow_client = client(uri)
    return [r.info.run_id for r in mlflow_client.search_runs([experiment_id(mlflow_client, uri, EXPERIMENT)])]


def _tracked_run(runs, run_id: str | None):
    """A finished run folder `runs/pulled/RUN` tracked in the local store `runs/mlflow.db` as training leaves
    it: in a run made there, or (`run_id`) in a run that store does not hold."""
    uri = f"sqlite:///{runs.resolve() / TRACKING_DB}"
    mlflow_client = client(uri)
    made = mlflow_client.create_run(experiment_id(mlflow_client, uri, EXPERIMENT)).info.run_id
    folder = runs / EXPERIMENT / "2026-01-01_00-00-00"
    folder.mkdir(parents=True)
    record = {"experiment": EXPERIMENT, "status": "completed", "steps": 4, "loggers": {
        "mlflow": {"run_id": run_id or made, "tracking_uri": uri, "experiment_name": EXPERIMENT}}}
    (folder / RUN_JSON).write_text(json.dumps(record))
    return folder, uri


@pytest.mark.parametrize("pusher_store", ["elsewhere", "same path, another store"])
def test_a_pulled_run_is_tracked_in_the_pullers_store(pusher_store, tmp_path, monkeypatch, capsys):
    pusher = tmp_path / "alice" / "runs"
    # "same path": this machine has a store at the path the pusher's run.json names (a clone at the same
    # path), which holds runs of its own but not the pusher's run
    elsewhere = pusher_store == "elsewhere"
    folder, pusher_uri = _tracked_run(pusher, None if elsewhere else uuid.uuid4().hex)
    remote = (tmp_path / "remote").as_uri()
    push_run(folder, remote)
    if elsewhere:
        shutil.rmtree(tmp_path / "alice")  # the pusher's machine: not this one
    else:
        shutil.rmtree(folder)
        before = _store_runs(pusher_uri)
    puller = tmp_path / "bob" / "runs"
    pulled, _, _ = pull_run(f"{EXPERIMENT}/{folder.name}", remote, root=puller)
    monkeypatch.setenv("SAMP_RUNS_DIR", str(puller))
    monkeypatch.delenv(TRACKING_ENV, raising=False)  # the default: the runs folder's local store
    out = pulled / "eval"
    out.mkdir()
    (out / "metrics.md").write_text("| rate |\n")

    run_id = track_evaluation(out, {"planner": "samp"}, {"eval/samp/val/success_rate": 0.5}, run_path=pulled)

    if elsewhere:
        assert not (tmp_path / "alice").exists(), "the evaluation wrote at the pusher's store path"
    else:
        assert _store_runs(pusher_uri) == before, "the store at the pusher's path got a run"
    puller_uri = f"sqlite:///{puller.resolve() / TRACKING_DB}"
    run = client(puller_uri).get_run(run_id)
    assert run.data.metrics == {"eval/samp/val/success_rate": 0.5}, run.data.metrics
    assert run.data.tags["samp.run_dir"] == str(pulled), run.data.tags
    notes = [line for line in capsys.readouterr().err.splitlines() if "records the MLflow store" in line]
    assert len(notes) == 1, f"expected one note on the recorded store, got: {notes}"
    why = "is not on this machine" if elsewhere else "does not hold its run"
    assert f"{pusher_uri}, which {why}" in notes[0] and f"tracking into {puller_uri} instead" in notes[0], notes[0]
