"""Sweeps as submitit jobs (`hydra/launcher=runs_submitit_local`: runs_slurm's job semantics, run by submitit's
LOCAL executor): a two-member sweep (two seeds of the quickstart experiment, shrunk) completes with each
member a pickled call in a process of its own, its run folder complete (run.json completed, eval/metrics.json)
and submitit's folder and logs in the sweep folder; run again, both jobs skip their completed member; a DDP
sweep through it is refused (only SLURM starts the ranks). And the local launchers are the SLURM ones' job
semantics: the same resources, time limit and submitit folder."""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
# The suite's shrunk policy run (tests/test_readme.py's POLICY): the smoke dataset, grids at n_e 16, four
# training batches of one epoch, one evaluation problem per split and no benchmark.
POLICY = ["datamodule.dataset=smoke", "datamodule.n_e=16", "datamodule.val_samples=50", "trainer.max_epochs=1",
          "+trainer.limit_train_batches=4", "trainer.enable_progress_bar=false", "evaluation.problems=1",
          "evaluation.benchmark=null"]
SDF_RUN = ["robot_sdf_samples=tiny", "trainer.max_steps=40", "robot_sdf_eval=tiny", "trainer.enable_progress_bar=false"]
MEMBERS = ("experiment=quickstart,seed=0", "experiment=quickstart,seed=1")
SWEEP = ["-m", "experiment=quickstart", "seed=0,1", *POLICY, "hydra/launcher=runs_submitit_local"]
JOB_KEYS = ("submitit_folder", "timeout_min", "cpus_per_task", "mem_gb", "nodes", "tasks_per_node", "gpus_per_node")


@pytest.fixture(scope="module")
def sweep(tmp_path_factory, cli):
    """(runs folder, sweep folder, the sweep's output): what the members need built first, one after the
    other (the smoke dataset, the small robot SDF), then the sweep through submitit."""
    runs = tmp_path_factory.mktemp("submitit_runs")
    for module, args in (("samp.data", ["generate", "dataset=smoke", "progress=false"]),
                         ("samp.train", ["experiment=robot_sdf_panda_quick", *SDF_RUN])):
        proc = cli(module, args, runs, timeout=900)
        assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    folder = runs / "sweeps" / "submitit"
    # tracked into the local store (the suite turns tracking off): members in parallel claim one parent run
    proc = cli("samp.train", [*SWEEP, f"hydra.sweep.dir={folder}"], runs, timeout=1500, env={"SAMP_TRACKING_URI": None})
    assert proc.returncode == 0, proc.stdout[-2000:] + proc.stderr[-3000:]
    return runs, folder, proc


def _jobs(folder: Path) -> list[Path]:
    """submitit's job folders (named by job id) in the sweep folder, where runs_submitit_local puts them."""
    return sorted(p for p in (folder / ".submitit").iterdir() if p.name.isdigit())


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_members_complete_as_submitit_jobs(sweep):
    runs, folder, proc = sweep
    assert "Submitit 'local' sweep output dir" in proc.stdout + proc.stderr
    assert sorted(p.name for p in folder.iterdir() if p.is_dir() and not p.name.startswith(".")) == sorted(MEMBERS)
    pids = set()
    for name, seed in zip(MEMBERS, (0, 1)):
        record = json.loads((folder / name / "run.json").read_text())
        assert record["status"] == "completed" and record["seed"] == seed, record["status"]
        assert record["sweep"]["member"] == name and record["run_dir"] == str(folder / name)
        assert (folder / name / "eval" / "metrics.json").is_file() and (folder / name / "checkpoints" / "last.ckpt").is_file()
        assert record["command"][0] == "_submit.py", record["command"]  # run by submitit's job entry point
        pids.add(record["pid"])
    assert len(pids) == 2, f"the members ran in one process: {pids}"
    jobs = _jobs(folder)
    assert len(jobs) == 2, sorted(p.name for p in (folder / ".submitit").iterdir())
    ran = []
    for job in jobs:
        for suffix in ("_submitted.pkl", "_0_result.pkl", "_0_log.out", "_0_log.err"):
            assert (job / f"{job.name}{suffix}").is_file(), f"{job.name}{suffix} missing in {job}"
        log = (job / f"{job.name}_0_log.out").read_text() + (job / f"{job.name}_0_log.err").read_text()
        assert f"JobEnvironment(job_id={job.name}," in log and "Job completed successfully" in log, log[-3000:]
        ran += [m for m in MEMBERS if f"run folder: {folder / m}\n" in log]  # the member's training logged here
    assert sorted(ran) == sorted(MEMBERS), f"each job's log should name its own member's folder: {ran}"
    for name in (".submitit", "multirun", "outputs"):  # submitit's and Hydra's default folders
        assert not (REPO / name).exists(), f"{name} written into the repository"
    assert list(runs.rglob(".submitit")) == [folder / ".submitit"]


@pytest.mark.slow
def test_members_in_parallel_processes_share_one_parent_run(sweep):
    """Each member, in its own process, finds or makes the sweep's MLflow run: one parent is left (a member
    that lost the claim deleted the one it made), and both members are its children."""
    from mlflow.tracking import MlflowClient

    runs, folder, _ = sweep
    tracked = [json.loads((folder / name / "run.json").read_text())["loggers"]["mlflow"] for name in MEMBERS]
    assert {t["tracking_uri"] for t in tracked} == {f"sqlite:///{runs.resolve()}/mlflow.db"}, tracked
    client = MlflowClient(tracked[0]["tracking_uri"])
    experiment = client.get_experiment_by_name("sweeps/submitit")
    active = {r.info.run_id: r for r in client.search_runs([experiment.experiment_id])}  # deleted runs left out
    (parent,) = [r for r in active.values() if r.data.tags.get("samp.kind") == "sweep"]
    assert sorted(active) == sorted([parent.info.run_id, *(t["run_id"] for t in tracked)]), sorted(active)
    assert {active[t["run_id"]].data.tags["mlflow.parentRunId"] for t in tracked} == {parent.info.run_id}


@pytest.mark.slow
@pytest.mark.timeout(2400)
def test_running_the_sweep_again_skips_both_members_in_their_jobs(sweep, cli):
    runs, folder, _ = sweep
    before = {m: (folder / m / "run.json").read_text() for m in MEMBERS}
    earlier = set(_jobs(folder))
    proc = cli("samp.train", [*SWEEP, f"hydra.sweep.dir={folder}"], runs, timeout=900)
    assert proc.returncode == 0, proc.stderr[-3000:]
    new = sorted(set(_jobs(folder)) - earlier)
    assert len(new) == 2, new
    logs = "".join((job / f"{job.name}_0_log.out").read_text() for job in new)
    assert logs.count("completed earlier, skipped") == 2, logs[-3000:]
    assert {m: (folder / m / "run.json").read_text() for m in MEMBERS} == before


@pytest.mark.parametrize("config, pair", [("train", ("runs_slurm", "runs_submitit_local")),
                                          ("data", ("shards_slurm", "shards_submitit_local"))])
def test_local_launchers_have_the_slurm_launchers_job_settings(config, pair, tmp_path, monkeypatch):
    """Same resources, time limit and submitit folder (under the sweep folder, under $SAMP_RUNS_DIR for the
    shards' default sweep folder); only the executor differs."""
    from hydra import compose, initialize_config_dir
    from omegaconf import OmegaConf

    from samp.paths import conf_dir

    monkeypatch.setenv("SAMP_RUNS_DIR", str(tmp_path))
    launchers = {}
    for name in pair:
        with initialize_config_dir(str(conf_dir()), version_base="1.3"):
            launchers[name] = compose(config, [f"hydra/launcher={name}"], return_hydra_config=True).hydra
    slurm, local = (OmegaConf.to_container(launchers[name].launcher) for name in pair)
    assert slurm["_target_"].endswith(".SlurmLauncher") and local["_target_"].endswith(".LocalLauncher")
    assert {k: local[k] for k in JOB_KEYS} == {k: slurm[k] for k in JOB_KEYS}
    assert local["submitit_folder"] == "${hydra.sweep.dir}/.submitit/%j"
    if config == "data":
        assert re.fullmatch(re.escape(str(tmp_path)) + r"/data_shards/[\d_-]+", str(launchers[pair[1]].sweep.dir))
    for name in pair:  # each file says how it is used
        text = (conf_dir() / "hydra" / "launcher" / f"{name}.yaml").read_text()
        assert f"hydra/launcher={name}" in text, name


@pytest.mark.slow
def test_a_ddp_sweep_through_the_local_launcher_is_refused(cli, tmp_path):
    """Only SLURM starts DDP ranks for Lightning; in a local submitit job Lightning would re-run the job per rank."""
    folder = tmp_path / "sweep"
    proc = cli("samp.train", ["-m", "experiment=quickstart", "seed=0,1", "trainer=ddp", "trainer.accelerator=cpu",
                              "hydra/launcher=runs_submitit_local", f"hydra.sweep.dir={folder}"], tmp_path)
    assert proc.returncode != 0 and "trainer.strategy=ddp in a sweep needs the SLURM launcher" in proc.stderr, \
        proc.stderr[-3000:]
    assert not list(folder.glob("*/run.json")), "a member started training"
