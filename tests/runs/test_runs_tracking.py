"""Tracking in MLflow, read back through a real `mlflow server` and its REST API (what `mlflow ui` shows):

* a quickstart run (shrunk: the smoke dataset, four batches, one problem per split) tracked in the local
  store under the runs folder, the default: its params, metric history, lineage tags, dataset input and
  artifacts against run.json and metrics.csv; with `logger=tensorboard`, its event files read back by
  TensorBoard's own reader;
* a two-member sweep tracked on the server itself (`SAMP_TRACKING_URI=http://...`, a team's server): its
  members are child runs of the sweep's run, their artifacts uploaded through the server;
* a re-evaluation of the quickstart run (`samp.eval run=...`, into `eval-2/`): a new section of the same
  MLflow run, not a new run; an evaluation of the straight line without a run: a run of the experiment `eval`.

The server serves the same sqlite file the local runs write, as `mlflow ui --backend-store-uri
sqlite:///runs/mlflow.db` does (docs/runs.md)."""

from __future__ import annotations

import csv
import json
import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # a server, three trainings and an evaluation in subprocesses

# The quickstart shrunk as tests/e2e and tests/test_readme.py shrink it.
QUICKSTART = ["+experiment=quickstart", "datamodule.dataset=smoke", "datamodule.n_e=16", "datamodule.val_samples=50",
              "trainer.max_epochs=1", "+trainer.limit_train_batches=4", "trainer.log_every_n_steps=2",
              "trainer.enable_progress_bar=false", "evaluation.problems=1", "evaluation.benchmark=null",
              "build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']",
              "logger=tensorboard"]
LOCAL = {"SAMP_TRACKING_URI": None}  # the default: the local store under the runs folder (the suite turns it off)
REEVAL = ["problems=1", "splits=[val]", "benchmark=null", "record=false"]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


class Rest:
    """MLflow's REST API (version 2.0) of a server, with urllib."""

    def __init__(self, url: str):
        self.url = url

    def get(self, endpoint: str, **query) -> dict:
        with urllib.request.urlopen(f"{self.url}/api/2.0/mlflow/{endpoint}?{urllib.parse.urlencode(query)}") as r:
            return json.loads(r.read())

    def post(self, endpoint: str, body: dict) -> dict:
        request = urllib.request.Request(f"{self.url}/api/2.0/mlflow/{endpoint}", data=json.dumps(body).encode(),
                                         headers={"Content-Type": "application/json"})
        with urllib.request.urlopen(request) as r:
            return json.loads(r.read())

    def runs(self, experiment: str) -> list[dict]:
        exp = self.get("experiments/get-by-name", experiment_name=experiment)["experiment"]
        return self.post("runs/search", {"experiment_ids": [exp["experiment_id"]], "max_results": 100}).get("runs", [])

    def run(self, run_id: str) -> dict:
        return self.get("runs/get", run_id=run_id)["run"]

    def history(self, run_id: str, key: str) -> list[tuple[int, float]]:
        found = self.get("metrics/get-history", run_id=run_id, metric_key=key).get("metrics", [])
        return sorted((int(m.get("step", 0)), float(m["value"])) for m in found)

    def artifacts(self, run_id: str, path: str = "") -> set[str]:
        """Every artifact file of the run under `path`, as relative paths."""
        files = self.get("artifacts/list", run_id=run_id, path=path).get("files", [])
        out = set()
        for f in files:
            out |= self.artifacts(run_id, f["path"]) if f["is_dir"] else {f["path"]}
        return out


def _tags(run: dict) -> dict[str, str]:
    return {t["key"]: t["value"] for t in run["data"].get("tags", [])}


def _params(run: dict) -> dict[str, str]:
    return {p["key"]: p["value"] for p in run["data"].get("params", [])}


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """(runs folder, REST client) of `mlflow server` on the local store `sqlite:///<runs>/mlflow.db`."""
    tmp = tmp_path_factory.mktemp("tracking")
    runs = tmp / "runs"
    runs.mkdir()
    port = _free_port()
    mlflow = shutil.which("mlflow", path=str(Path(sys.executable).parent))
    assert mlflow, "the `mlflow` command is missing: pip install -e '.[mlflow]' (the dev extra has it)"
    log = open(tmp / "server.log", "w")
    proc = subprocess.Popen([mlflow, "server", "--backend-store-uri", f"sqlite:///{runs}/mlflow.db",
                             "--artifacts-destination", str(tmp / "served-artifacts"), "--host", "127.0.0.1",
                             "--port", str(port), "--workers", "1"], stdout=log, stderr=subprocess.STDOUT,
                            cwd=tmp, env={**os.environ, "OMP_NUM_THREADS": "1"})
    url = f"http://127.0.0.1:{port}"
    try:
        while True:  # until it answers, or it exits (the pytest timeout bounds a server that hangs)
            if proc.poll() is not None:
                pytest.fail(f"mlflow server exited with {proc.returncode}: {(tmp / 'server.log').read_text()[-3000:]}")
            try:
                with urllib.request.urlopen(f"{url}/health") as r:
                    if r.status == 200:
                        break
            except OSError:
                time.sleep(0.5)
        yield runs, Rest(url)
    finally:
        proc.terminate()
        proc.wait(timeout=60)
        log.close()


@pytest.fixture(scope="module")
def quickstart(server, cli):
    """The quickstart run's folder and run.json, tracked in the local store (no tracking setting given)."""
    runs, _ = server
    proc = cli("samp.train", QUICKSTART, runs, timeout=900, env=LOCAL)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    (folder,) = (runs / "quickstart").iterdir()
    return folder, json.loads((folder / "run.json").read_text())


def test_the_run_is_tracked_in_the_local_store_with_params_tags_and_lineage(server, quickstart):
    runs, rest = server
    folder, record = quickstart
    assert record["loggers"]["mlflow"]["tracking_uri"] == f"sqlite:///{runs.resolve()}/mlflow.db"
    (run,) = rest.runs("quickstart")
    assert run["info"]["run_id"] == record["loggers"]["mlflow"]["run_id"]
    assert run["info"]["status"] == "FINISHED" and run["info"]["run_name"] == f"quickstart/{folder.name}"
    params = _params(run)  # the resolved config, as dotted keys
    assert params["trainer.max_epochs"] == "1" and params["datamodule.n_e"] == "16" and params["seed"] == "0", params
    assert params["tracking.recording"] == "True" and params["run_dir"] == str(folder)
    tags = _tags(run)
    assert tags["samp.dataset_id"] == record["dataset_id"] and tags["samp.experiment"] == "quickstart"
    assert tags["samp.robot_sdf_artifact_id"] == record["robot_sdf_artifact_id"]
    assert tags["samp.git_commit"] == str(record["code_version"]["git_commit"])
    (dataset,) = run["inputs"]["dataset_inputs"]  # the dataset as an MLflow dataset input, its id as the digest
    name, content_id = record["dataset_id"].split("@")
    assert dataset["dataset"]["name"] == name and dataset["dataset"]["digest"] == content_id
    assert {t["key"]: t["value"] for t in dataset["tags"]} == {"mlflow.data.context": "training"}


def test_metric_history_matches_metrics_csv(server, quickstart):
    _, rest = server
    folder, record = quickstart
    run_id = record["loggers"]["mlflow"]["run_id"]
    rows = list(csv.DictReader((folder / "metrics.csv").open()))
    want = [(int(r["step"]), float(r["train/loss"])) for r in rows if r.get("train/loss")]
    got = rest.history(run_id, "train/loss")
    assert len(want) >= 2 and [s for s, _ in got] == [s for s, _ in want], (want, got)
    assert [v for _, v in got] == pytest.approx([v for _, v in want], rel=1e-6)
    rate = "eval/samp/val/success_rate"  # an evaluation section's rate with its interval bounds
    for key in (rate, f"{rate}_ci_low", f"{rate}_ci_high"):
        assert [v for _, v in rest.history(run_id, key)] == [pytest.approx(record["metrics"][key])], key


def test_artifacts_hold_the_plots_card_tables_and_recording(server, quickstart):
    _, rest = server
    folder, record = quickstart
    files = rest.artifacts(record["loggers"]["mlflow"]["run_id"])
    for name in ("plots/summary.png", "MODEL_CARD.md", "eval/metrics.md", "eval/problems.jsonl", "eval/metrics.json",
                 "eval/recording.rrd", "metrics.csv", "run.json"):
        assert name in files, f"{name} is not an artifact; artifacts: {sorted(files)}"
        assert (folder / name).is_file()
    assert not any(f.startswith(("checkpoints/", "tensorboard/")) for f in files), sorted(files)


def test_the_robot_sdf_built_for_it_is_tracked_too(server, quickstart):
    _, rest = server
    _, record = quickstart
    (sdf,) = rest.runs("robot_sdf_panda_quick")
    assert _tags(sdf)["samp.robot_sdf_artifact_id"] == record["robot_sdf_artifact_id"]
    assert rest.history(sdf["info"]["run_id"], "train/loss"), "the robot SDF run has no learning curve"


def test_tensorboard_event_files_hold_the_curves_and_rates(quickstart):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    folder, record = quickstart
    events = EventAccumulator(str(folder / "tensorboard"))
    events.Reload()
    scalars = events.Tags()["scalars"]
    rows = list(csv.DictReader((folder / "metrics.csv").open()))
    want = [(int(r["step"]), float(r["train/loss"])) for r in rows if r.get("train/loss")]
    got = [(e.step, e.value) for e in events.Scalars("train/loss")]
    assert [s for s, _ in got] == [s for s, _ in want] and [v for _, v in got] == pytest.approx(
        [v for _, v in want], rel=1e-6), (want, got)
    rate = "eval/samp/val/success_rate"
    assert rate in scalars, sorted(scalars)
    assert [e.value for e in events.Scalars(rate)] == [pytest.approx(record["metrics"][rate])]


def test_a_sweep_on_the_server_has_its_members_as_child_runs(server, cli, tiny_sdf):
    """The team case: the pipeline pointed at the server's URI; the runs folders stay the source of files."""
    runs, rest = server
    folder = runs / "sweeps" / "seeds"
    proc = cli("samp.train", ["-m", "+experiment=robot_sdf_panda", "seed=0,1", "trainer.max_steps=20", *tiny_sdf,
                              f"hydra.sweep.dir={folder}"], runs, env={"SAMP_TRACKING_URI": rest.url})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    found = {r["info"]["run_name"]: r for r in rest.runs("sweeps/seeds")}
    (parent,) = [r for name, r in found.items() if name == "seeds"]
    members = {name: r for name, r in found.items() if name != "seeds"}
    assert sorted(members) == ["experiment=robot_sdf_panda,seed=0", "experiment=robot_sdf_panda,seed=1"], sorted(found)
    for name, run in members.items():
        record = json.loads((folder / name / "run.json").read_text())
        assert record["loggers"]["mlflow"] == {"run_id": run["info"]["run_id"], "tracking_uri": rest.url,
                                               "experiment_name": "sweeps/seeds"}
        assert _tags(run)["mlflow.parentRunId"] == parent["info"]["run_id"]
        assert _params(run)["seed"] == str(record["seed"])
        assert [s for s, _ in rest.history(run["info"]["run_id"], "train/loss")][-1] <= 20
        assert {"metrics.csv", "run.json"} <= rest.artifacts(run["info"]["run_id"])  # uploaded through the server
    assert not (runs / "mlflow-artifacts" / "sweeps").exists(), "a server's run wrote artifacts into the local store"


def test_a_reevaluation_is_a_new_section_of_the_same_run(server, quickstart, cli):
    runs, rest = server
    folder, record = quickstart
    proc = cli("samp.eval", [f"run={folder}", *REEVAL], runs, env=LOCAL)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    run_id = record["loggers"]["mlflow"]["run_id"]
    assert f"tracked: {record['loggers']['mlflow']['tracking_uri']} run {run_id} (eval-2)" in proc.stdout
    (run,) = rest.runs("quickstart")  # no second run
    assert run["info"]["run_id"] == run_id
    report = json.loads((folder / "eval-2" / "metrics.json").read_text())
    rate = report["metrics"]["val"]
    for key in ("success_rate", "success_rate_ci_low", "success_rate_ci_high"):
        assert [v for _, v in rest.history(run_id, f"eval-2/samp/val/{key}")] == [pytest.approx(rate[key])], key
    assert {"eval-2/metrics.md", "eval-2/problems.jsonl", "eval-2/metrics.json"} <= rest.artifacts(run_id, "eval-2")
    assert [v for _, v in rest.history(run_id, "eval/samp/val/success_rate")] == [
        pytest.approx(record["metrics"]["eval/samp/val/success_rate"])], "the first evaluation's section changed"


def test_a_samp_check_evaluation_is_tracked_under_a_name_mlflow_takes(server, quickstart, cli, tmp_path):
    """MLflow refuses `+` in metric names: samp+check's metrics go to the run as `samp_check`, and the
    evaluation exits cleanly (it used to fail after writing its files)."""
    runs, rest = server
    folder, record = quickstart
    out = tmp_path / "check"
    proc = cli("samp.eval", [f"run={folder}", *REEVAL, "check=2", f"out={out}"], runs, env=LOCAL)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    report = json.loads((out / "metrics.json").read_text())
    assert report["planner"] == "samp+check"
    run_id = record["loggers"]["mlflow"]["run_id"]
    got = rest.history(run_id, "check/samp_check/val/success_rate")
    assert [v for _, v in got] == [pytest.approx(report["metrics"]["val"]["success_rate"])]


def test_an_evaluation_without_a_run_is_a_run_of_the_eval_experiment(server, quickstart, cli):
    runs, rest = server
    _, record = quickstart
    proc = cli("samp.eval", ["planner=straight", "dataset=smoke", *REEVAL], runs, env=LOCAL)
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    (run,) = rest.runs("eval")
    assert run["info"]["run_name"] == f"eval/straight_{record['dataset_id']}" and run["info"]["status"] == "FINISHED"
    report = json.loads((runs / "eval" / f"straight_{record['dataset_id']}" / "metrics.json").read_text())
    got = rest.history(run["info"]["run_id"], "eval/straight/val/success_rate")
    assert [v for _, v in got] == [pytest.approx(report["metrics"]["val"]["success_rate"])]
    (dataset,) = run["inputs"]["dataset_inputs"]
    assert dataset["dataset"]["digest"] == record["dataset_id"].split("@")[1]
    assert {t["key"]: t["value"] for t in dataset["tags"]} == {"mlflow.data.context": "evaluation"}
    assert {"eval/metrics.md", "eval/problems.jsonl"} <= rest.artifacts(run["info"]["run_id"])


def test_ls_and_show_say_where_runs_are_tracked(server, quickstart, cli):
    runs, _ = server
    folder, record = quickstart
    uri, run_id = record["loggers"]["mlflow"]["tracking_uri"], record["loggers"]["mlflow"]["run_id"]
    shown = cli("samp.runs", ["show", str(folder)], runs)
    assert shown.returncode == 0 and f"tracked    {uri} run {run_id}" in shown.stdout, shown.stdout + shown.stderr
    listed = cli("samp.runs", ["ls", "experiment=quickstart"], runs)
    assert listed.returncode == 0 and run_id in listed.stdout and f"tracked in {uri}: 1 run(s)" in listed.stdout, \
        listed.stdout + listed.stderr


def test_which_files_become_artifacts(server, tmp_path):
    """Checkpoints, exported networks, other loggers' folders and hidden files stay out; recordings go only
    when asked (`tracking.recording`)."""
    from samp.tracking import client, experiment_id, log_files

    _, rest = server
    for name in ("eval/metrics.md", "eval/recording.rrd", "checkpoints/last.ckpt", "robot_sdf.pt", "tensorboard/ev",
                 ".hydra/config.yaml", ".run.json.tmp", "plots/summary.png"):
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(name)
    mlflow_client = client(rest.url)
    experiment = experiment_id(mlflow_client, rest.url, "files")
    for recording, want in ((False, ["eval/metrics.md", "plots/summary.png"]),
                            (True, ["eval/metrics.md", "eval/recording.rrd", "plots/summary.png"])):
        run_id = mlflow_client.create_run(experiment).info.run_id
        assert log_files(mlflow_client, run_id, tmp_path, recording=recording) == want
        assert rest.artifacts(run_id) == set(want)
