"""The demo pipeline end to end through the real CLI (`make demo` runs the same command at full size):
`python -m samp.train +experiment=quickstart` on a fresh registry builds the dataset (the `smoke` spec) and
the robot SDF (tiny settings), trains the policy briefly, evaluates it beside the expert and the straight
line, and leaves every artifact a user is pointed to."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow


def _tree(root: Path) -> dict[str, int]:
    """Every file under `root` with its mtime, Python caches and the git folder left out."""
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = [d for d in dirnames if d not in ("__pycache__", ".pytest_cache", ".git", ".venv")]
        out.update({os.path.join(dirpath, f): os.stat(os.path.join(dirpath, f)).st_mtime_ns for f in filenames})
    return out


@pytest.fixture(scope="module")
def demo(tmp_path_factory, _isolated_cache):
    """The pipeline run from a folder of its own with the run and dataset folders given as config
    (`paths.runs_dir`, `paths.datasets_dir`; the environment variables unset): every reader and writer of
    the recipe, the robot SDF it builds and its evaluations included, must go there, and nothing into the
    repository or the working folder."""
    tmp = tmp_path_factory.mktemp("demo")
    # SAMP_TRACKING_URI unset too: the demo is tracked in its runs folder's local MLflow store, as by default
    env = {k: v for k, v in os.environ.items() if k not in ("SAMP_RUNS_DIR", "SAMP_DATASETS_DIR", "SAMP_TRACKING_URI")}
    repo = Path(__file__).resolve().parents[2]
    env["PYTHONPATH"] = str(repo)
    (tmp / "work").mkdir()
    before = _tree(repo)
    cmd = [sys.executable, "-m", "samp.train", "+experiment=quickstart", "datamodule.dataset=smoke",
           f"paths.runs_dir={tmp / 'runs'}", f"paths.datasets_dir={tmp / 'datasets'}",
           "datamodule.n_e=16", "datamodule.val_samples=50", "trainer.max_epochs=1",
           "+trainer.limit_train_batches=4", "trainer.log_every_n_steps=2", "evaluation.problems=2",
           "evaluation.benchmark=smoke",
           "build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env=env, cwd=tmp / "work")
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    (run,) = (tmp / "runs" / "quickstart").iterdir()
    after = _tree(repo)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"the pipeline wrote into the repository: {changed[:20]}"
    assert not any((tmp / "work").iterdir()), f"the pipeline wrote into its working folder: {list((tmp / 'work').iterdir())}"
    assert sorted(p.name for p in tmp.iterdir()) == ["datasets", "runs", "work"]
    LOGS["stderr"] = out.stderr  # for the log test; the others read stdout
    return tmp, run, out.stdout


LOGS: dict[str, str] = {}


def _rows(text: str, planner: str, group: str) -> int:
    """How many lines of `text` are the printed table's row for (planner, group); the compact table pads
    its cells to the column's width."""
    return len(re.findall(rf"^\| {re.escape(planner)} +\| {re.escape(group)} +\|", text, re.M))


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
        for group in ("val", "train", "benchmark"):
            for key in ("success_rate", "success_rate_ci_low", "success_rate_ci_high", "collision_rate"):
                assert f"eval/{planner}/{group}/{key}" in record["metrics"], (planner, group, sorted(record["metrics"]))
    assert "eval/samp/benchmark/solution_time_b1_mean" in record["metrics"]


def test_metrics_recording_and_plot_are_there(demo):
    _, run, stdout = demo
    report = json.loads((run / "eval" / "metrics.json").read_text())
    assert report["protocol"] == 2 and report["benchmark"].startswith("bench_smoke@")
    for key in ("metrics", "expert", "straight"):
        assert set(report[key]) >= {"val", "train", "benchmark", "val_hard", "benchmark_hard"}, (key, sorted(report[key]))
        assert report[key]["train"]["problems"] == 2 and report[key]["benchmark"]["problems"] == 8
        for group, m in report[key].items():  # every rate with its interval
            if m["problems"]:
                assert m["success_rate_ci_low"] <= m["success_rate"] <= m["success_rate_ci_high"], (key, group)
    assert {f"benchmark_{g}" for g in ("tabletop", "shelf", "cabinet", "blocks")} <= set(report["metrics"])
    m = report["metrics"]["benchmark"]
    assert m["timed_problems"] == 8 and m["solution_time_b1_mean"] > 0 and m["step_time_b1_mean"] > 0
    assert report["expert"]["train"]["success_rate"] == 1.0  # the expert's own stored solutions
    assert (run / "plots" / "summary.png").stat().st_size > 10_000
    recording = run / "eval" / "recording.rrd"
    rerun = Path(sys.executable).with_name("rerun")
    rerun = str(rerun) if rerun.is_file() else shutil.which("rerun")
    assert rerun, "the rerun CLI (rerun-sdk) is not installed next to this Python"
    check = subprocess.run([rerun, "rrd", "verify", str(recording)], capture_output=True, text=True, timeout=300)
    assert check.returncode == 0, check.stderr[-2000:]
    # The run ends by printing the table and where its files are.
    assert _rows(stdout, "samp", "val") and _rows(stdout, "straight", "benchmark") \
        and _rows(stdout, "expert", "benchmark_hard"), stdout[-3000:]
    assert f"recording: {recording}" in stdout and f"plots: {run / 'plots' / 'summary.png'}" in stdout


def test_the_checkpoint_alone_replays_the_evaluated_rollout(demo):
    """Reloaded from the run folder in another process, the policy takes exactly the steps recorded by the
    evaluation at the end of training (problems.jsonl): the run folder alone rebuilds the evaluated model.
    (That a checkpoint reloads to the in-memory model's outputs is tests/policy/test_policy_system.py's.)"""
    import torch

    from samp.data import open_dataset
    from samp.eval import load_planner
    from samp.eval.planners import EnvBatch

    tmp, run, _ = demo
    record = next(r for r in map(json.loads, (run / "eval" / "problems.jsonl").read_text().splitlines())
                  if r["planner"] == "samp" and r["steps"] >= 3 and r["group"] in ("val", "train"))
    policy = load_planner(run)
    ds = open_dataset("smoke", tmp / "datasets")
    scene = ds.scenes[record["scene_index"]]
    env = EnvBatch(ds.grid(record["scene_index"], policy.n_e)[None].float(),
                   torch.tensor([scene.bounds], dtype=torch.float32), torch.zeros(1, dtype=torch.long))
    policy.reset(env)
    traj = torch.tensor(record["trajectory"], dtype=torch.float32)
    goal = torch.tensor(record["q_goal"], dtype=torch.float32)[None]
    for t in range(3):
        got = policy.step(traj[t][None], goal, env)[0]
        torch.testing.assert_close(got, traj[t + 1], atol=1e-5, rtol=0, msg=f"step {t}: reloaded policy differs")


def test_no_reported_problem_comes_from_what_the_run_trained_or_selected_on(demo):
    """By content: no benchmark scene is a training or validation scene of the run's dataset, and no
    evaluation problem is a training demonstration (its start and goal)."""
    import numpy as np

    from samp.data import open_dataset

    tmp, run, _ = demo
    ds, bench = open_dataset("smoke", tmp / "datasets"), open_dataset("bench_smoke", tmp / "datasets")
    seen = {h for h, split in zip(ds.scene_hashes, ds.scene_split) if split in ("train", "val")}
    assert seen and not seen & set(bench.scene_hashes)
    assert [s.content_hash() for s in bench.scenes] == bench.scene_hashes, "the manifest's hashes are the scenes'"
    demos = {(tuple(np.round(t[0].numpy(), 9)), tuple(np.round(t[-1].numpy(), 9))) for t in ds.trajectories}
    records = [json.loads(x) for x in (run / "eval" / "problems.jsonl").read_text().splitlines()]
    asked = {(tuple(np.round(r["q_start"], 9)), tuple(np.round(r["q_goal"], 9))) for r in records}
    assert asked and not asked & demos, "an evaluation problem is a training demonstration"
    bench_names = {s.name for s in bench.scenes}
    assert {r["scene"] for r in records if r["group"] == "benchmark"} <= bench_names


def test_an_unknown_experiment_lists_the_available_ones():
    out = subprocess.run([sys.executable, "-m", "samp.train", "+experiment=quikstart"], capture_output=True, text=True,
                         timeout=300)
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    assert "Could not find 'experiment/quikstart'" in out.stderr and "quickstart" in out.stderr, out.stderr[-2000:]


def test_the_log_is_quiet_and_kept_in_the_run_folder(demo):
    """Captured as a cluster log would be (not a terminal): no progress redraws, no nanobind leak reports
    from the dataset workers, no pybullet banner, no Lightning tip, the table once; train.log has it all."""
    _, run, stdout = demo
    log = stdout + LOGS["stderr"]
    for noise in ("\r", "\x1b[", "nanobind: leaked", "pybullet build time", "Tip:"):
        assert noise not in log, f"{noise!r} in the captured output:\n{log[-3000:]}"
    assert _rows(log, "samp", "val") == 1, "the results table is not printed exactly once:\n" + log[-3000:]
    assert "epoch 0 done: step 4" in LOGS["stderr"], "no line of training progress in place of the bar"
    kept = (run / "train.log").read_text()
    assert f"run folder: {run}" in kept and _rows(kept, "samp", "val") == 1 and "epoch 0 done" in kept
    assert "GPU available:" in kept, "Lightning's own log lines are not in train.log"
    assert "\r" not in kept


def test_the_run_plots_are_there(demo):
    """After training: the learning curves (with the learning rate logged in metrics.csv), the outcomes and
    the SDF slice of an evaluated scene; `python -m samp.runs plot RUN kind=run` draws them again."""
    _, run, stdout = demo
    header = (run / "metrics.csv").read_text().splitlines()[0].split(",")
    assert any(h.startswith("lr-") for h in header), header
    for name in ("learning.png", "outcomes.png", "sdf_slice.png"):
        path = run / "plots" / name
        assert path.is_file() and path.read_bytes()[:4] == b"\x89PNG", name
        assert f"plot: {path}" in stdout
    out = subprocess.run([sys.executable, "-m", "samp.runs", "plot", str(run), "kind=run", f"out={run / 'again'}"],
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert sorted(p.name for p in (run / "again").iterdir()) == ["learning.png", "outcomes.png", "sdf_slice.png"]


def test_the_policy_run_has_a_model_card(demo):
    _, run, _ = demo
    card = (run / "MODEL_CARD.md").read_text()
    record = json.loads((run / "run.json").read_text())
    assert f"dataset: `{record['dataset_id']}`" in card and f"artifact `{record['robot_sdf_artifact_id']}`" in card
    assert "| samp | benchmark |" in card, "the benchmark results are in the card"


def test_the_run_is_tracked_in_the_runs_folder(demo):
    """Tracked by default in `<runs>/mlflow.db`, its artifacts beside it (tests/runs/test_runs_tracking.py checks
    what the store holds); the robot SDF built for it is a tracked run too."""
    tmp, run, out = demo
    record = json.loads((run / "run.json").read_text())
    uri = f"sqlite:///{(tmp / 'runs').resolve()}/mlflow.db"
    assert record["loggers"]["mlflow"]["tracking_uri"] == uri and f"tracked: {uri} run " in out
    assert (tmp / "runs" / "mlflow-artifacts" / "quickstart").is_dir() and (tmp / "runs" / "mlflow.db").is_file()
    (sdf_run,) = (tmp / "runs" / "robot_sdf_panda_quick").iterdir()
    assert json.loads((sdf_run / "run.json").read_text())["loggers"]["mlflow"]["tracking_uri"] == uri
    from mlflow.tracking import MlflowClient

    tags = MlflowClient(uri).get_run(record["loggers"]["mlflow"]["run_id"]).data.tags  # the benchmark's id as a tag
    assert tags["samp.benchmark_id"] == json.loads((run / "eval" / "metrics.json").read_text())["benchmark"], tags
