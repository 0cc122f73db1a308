"""Run records without training: the git lineage of a real repository (clean, then dirty), metrics.csv
trimmed to a checkpoint, the paper's tables from run folders with known evaluations, and the configs of
the trainer and sweep groups (the logger group: test_runs_loggers.py)."""

from __future__ import annotations

import json
import subprocess

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


def _git(repo, *args) -> str:
    out = subprocess.run(["git", *args], cwd=repo, capture_output=True, text=True, check=True,
                         env={"GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@t", "GIT_COMMITTER_NAME": "t",
                              "GIT_COMMITTER_EMAIL": "t@t", "PATH": "/usr/bin:/bin:/usr/local/bin", "HOME": str(repo)})
    return out.stdout.strip()


def test_record_names_the_commit_and_flags_a_dirty_tree(tmp_path, monkeypatch):
    import samp.provenance as provenance
    from samp.runs import RunFolder

    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "code.py").write_text("x = 1\n")
    _git(repo, "add", "code.py")
    _git(repo, "commit", "-q", "-m", "first")
    commit = _git(repo, "rev-parse", "HEAD")
    monkeypatch.setattr(provenance, "REPO_ROOT", repo)
    provenance.code_version.cache_clear()
    try:
        clean = RunFolder.create(tmp_path / "runs", "exp")
        with clean.record(seed=5):
            pass
        (repo / "code.py").write_text("x = 2\n")  # an uncommitted change to a tracked file
        provenance.code_version.cache_clear()
        dirty = RunFolder.create(tmp_path / "runs", "exp")
        with dirty.record(seed=5):
            pass
    finally:
        provenance.code_version.cache_clear()
    assert clean.read()["code_version"] == {"package": provenance.__version__, "git_commit": commit, "git_dirty": False}
    assert dirty.read()["code_version"] == {"package": provenance.__version__, "git_commit": commit, "git_dirty": True}
    assert clean.read()["status"] == "completed" and clean.read()["pid"] > 0


def test_trim_metrics_sets_aside_rows_past_the_checkpoint(tmp_path):
    from samp.runs import RunFolder

    folder = RunFolder.create(tmp_path, "exp")
    (folder.path / "metrics.csv").write_text("epoch,step,train/loss\n0,4,1.0\n0,9,0.5\n1,14,0.25\n,,\n")
    assert folder.trim_metrics(10) == 1
    assert (folder.path / "metrics.csv").read_text().splitlines() == ["epoch,step,train/loss", "0,4,1.0", "0,9,0.5", ",,"]
    assert (folder.path / "metrics.superseded.csv").read_text().splitlines() == ["epoch,step,train/loss", "1,14,0.25"]
    with pytest.raises(ValueError, match="already holds a run"):
        (folder.path / "run.json").write_text("{}")
        RunFolder.create_at(folder.path)


def _evaluated_run(root, experiment: str, start: str, metrics: dict, expert: dict | None = None, **record):
    """A run folder holding a completed record and an eval/metrics.json with the given per-split metrics."""
    folder = root / experiment / start.replace(":", "-")
    (folder / "eval").mkdir(parents=True)
    (folder / "run.json").write_text(json.dumps({"status": "completed", "experiment": experiment, "start": start,
                                                 "dataset_id": "paper@abc", **record}))
    (folder / "eval" / "metrics.json").write_text(json.dumps({"planner": "samp", "dataset": "paper@abc",
                                                              "metrics": metrics, "expert": expert}))
    return folder


def _split(success, reach, collision, time_s, length, infer=None) -> dict:
    return {"success_rate": success, "reach_rate": reach, "collision_rate": collision, "solution_time_mean": time_s,
            "path_length_mean": length, "inference_time_mean": infer}


def test_paper_tables_fill_rows_from_runs_and_dash_the_rest(tmp_path, monkeypatch):
    from samp.runs.__main__ import main

    samp = {"train": _split(0.82, 0.88, 0.10, 0.073, 0.8), "heldout": _split(0.75, 0.83, 0.13, 0.074, 1.0),
            "all": _split(0.78, 0.85, 0.12, 0.0735, 0.9, infer=1.5e-3)}
    expert = {"train": _split(1.0, 1.0, 0.0, 0.79, 0.7), "heldout": _split(1.0, 1.0, 0.0, 0.81, 0.8)}
    _evaluated_run(tmp_path, "samp_n100", "2026-01-01T00:00:00", {"train": _split(0, 0, 1, 9, 9)})  # older: unused
    _evaluated_run(tmp_path, "samp_n100", "2026-01-02T00:00:00", samp, expert, epochs=4, fit_time_s=1080.0)
    main(["paper-tables", "--root", str(tmp_path), "--out", str(tmp_path / "tables")])
    one = (tmp_path / "tables" / "table_1.md").read_text()  # protocol-1 runs: "train / held-out" cells, marked
    assert ("| Expert (OMPL) (protocol 1: train / held-out) | 0.79 / 0.81 | 0.7 / 0.8 | 100 / 100 | 0 / 0 | - | - | - "
            "| samp_n100/2026-01-02T00-00-00 (paper@abc) |") in one
    assert "| SAMP (100 anchors) (protocol 1: train / held-out) | 0.073 / 0.074 | 0.8 / 1 | 82 / 75 | 10 / 13 | - | - | - |" in one
    assert "| MPiNet | - | - | - | - | - | - | - | - |" in one and "| SAMP (160 anchors) | - |" in one
    assert "| Straight line (joint space) | - | - | - | - | - | - | - | - |" in one  # no straight block in these evaluations
    two = (tmp_path / "tables" / "table_2.md").read_text()
    assert "| 100 (protocol 1: train / held-out) | 270 | 0.0015 | 82 / 75 | 88 / 83 | 10 / 13 |" in two
    assert "| 40 | - | - | - | - | - | - |" in two
    assert (tmp_path / "tables" / "table_2.csv").read_text().splitlines()[3].startswith(
        "100 (protocol 1: train / held-out),270,0.0015,82 / 75,88 / 83,10 / 13")


def test_ddp_trainer_and_sweep_configs_compose():
    from hydra.utils import get_object
    from omegaconf import OmegaConf

    from samp.paths import conf_dir
    from samp.train import compose_train_config

    cfg = compose_train_config(["+experiment=samp_n100", "trainer=ddp"])
    assert cfg.trainer.strategy == "ddp" and cfg.trainer.accelerator == "gpu" and cfg.trainer.sync_batchnorm
    get_object(cfg.trainer._target_)
    for name, members in (("anchor_size", [f"samp_n{n}" for n in (40, 70, 100, 130, 160)]),
                          ("loss_ablation", ["samp_n100", "samp_no_coll_loss", "samp_no_pointnet"]),
                          ("paper_table_1", ["samp_n100", "samp_n160", "mpnet", "simpnet", "mpinet"])):
        params = OmegaConf.load(conf_dir() / "sweep" / f"{name}.yaml").hydra.sweeper.params
        assert params["experiment"].split(",") == members
        for experiment in members:  # every member composes
            compose_train_config([f"+experiment={experiment}"])


def test_a_run_too_short_to_log_still_gets_its_metrics_csv(tmp_path):
    """A run that ends before `log_every_n_steps` and is not evaluated logged nothing: the last values of the
    run become metrics.csv's one row. A run that logged rows gets no extra one."""
    import csv

    from samp.runs.loggers import RunCSVLogger, finish_loggers

    short = RunCSVLogger(str(tmp_path / "short"))
    finish_loggers([short], {"epochs": 0}, {}, step=3, final={"train/loss": 0.5, "note": "text"})
    rows = list(csv.DictReader((tmp_path / "short" / "metrics.csv").open()))
    assert rows == [{"epoch": "0.0", "step": "3", "train/loss": "0.5"}], rows
    logged = RunCSVLogger(str(tmp_path / "logged"))
    logged.log_metrics({"train/loss": 0.7}, step=1)
    finish_loggers([logged], {"epochs": 0}, {}, step=3, final={"train/loss": 0.5})
    rows = list(csv.DictReader((tmp_path / "logged" / "metrics.csv").open()))
    assert [r["train/loss"] for r in rows] == ["0.7"], rows


def test_the_resume_hint_appears_only_when_the_run_can_be_resumed(tmp_path):
    """Interrupted before its first checkpoint, `resume=` would refuse the run: the message says to start
    again. With checkpoints/last.ckpt it gives the resume command, the folder quoted for the shell."""
    from samp.runs import RunFolder
    from samp.runs.folder import Terminated
    from samp.train.cli import interrupted_hint

    run = RunFolder.create_at(tmp_path / "sweep" / "experiment=samp_n40,seed=0")
    early = interrupted_hint(Terminated("SIGTERM"), run)
    assert "cannot be resumed" in early and "start it again" in early and "resume=" not in early, early
    run.last_checkpoint.parent.mkdir(parents=True, exist_ok=True)
    run.last_checkpoint.write_bytes(b"checkpoint")
    late = interrupted_hint(KeyboardInterrupt(), run)
    assert late.endswith(f"""continue with `python -m samp.train 'resume="{run.path}"'`"""), late
    from hydra.core.override_parser.overrides_parser import OverridesParser

    given = late.split("`")[1].split(" ", 3)[3][1:-1]  # what the shell hands over: resume="..."
    assert OverridesParser.create().parse_override(given).value() == str(run.path), "Hydra reads another folder"


def test_tables_by_dotted_keys_get_files_of_their_own(tmp_path):
    from samp.runs.tables import write_table

    a = write_table(tmp_path / "table_by_datamodule.n_e", ["datamodule.n_e"], [["40"]])
    b = write_table(tmp_path / "table_by_datamodule.dataset", ["datamodule.dataset"], [["smoke"]])
    assert [p.name for p in a + b] == ["table_by_datamodule.n_e.md", "table_by_datamodule.n_e.csv",
                                       "table_by_datamodule.dataset.md", "table_by_datamodule.dataset.csv"]
    assert "40" in a[0].read_text() and "smoke" in b[0].read_text()
    assert [p.name for p in write_table(tmp_path / "mine.md", ["k"], [["v"]])] == ["mine.md", "mine.csv"]


def test_runs_group_by_the_config_key_when_a_metric_has_the_same_name(tmp_path):
    """`by=loss` means the named loss (config group `loss`), not Lightning's `loss` metric that every run also
    records; a key only metrics have still groups by the metric."""
    from samp.runs.plots import _groups
    from samp.runs.registry import find_runs
    from samp.runs.tables import group_table

    for i, (name, final) in enumerate([("paper", 0.021), ("paper", 0.019), ("tau_1cm", 0.024)]):
        folder = tmp_path / "sweep" / f"member{i}"
        folder.mkdir(parents=True)
        (folder / "run.json").write_text(json.dumps({
            "status": "completed", "config": {"loss": name, "name": "samp_cpu"},
            "metrics": {"loss": final, "val/loss": final, "eval/samp/benchmark/success_rate": 0.5 + i / 10}}))
    runs = find_runs(tmp_path / "sweep")
    _, rows = group_table(runs, "loss", ["eval/samp/benchmark/success_rate"])
    assert [(row[0], row[1]) for row in rows] == [("paper", "2"), ("tau_1cm", "1")]
    assert list(_groups(runs, "loss")) == ["paper", "tau_1cm"]
    _, rows = group_table(runs, "val/loss", ["eval/samp/benchmark/success_rate"])
    assert len(rows) == 3  # a metric alone still groups
