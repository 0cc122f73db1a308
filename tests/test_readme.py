"""The README and the documentation site as a test: every command of the fenced shell blocks of README.md
and docs/*.md is run here, shrunk (the tiny `smoke` dataset, a few steps, one or two problems), from a
working folder outside the repository with `SAMP_DATASETS_DIR`, `SAMP_RUNS_DIR` and `SAMP_CACHE_DIR` in a
temporary folder; each must succeed and write what the page says where it says (under the configured
folders), and nothing may be written into the repository.

`STEPS` maps each documented command, exactly as the pages spell it (comments dropped, lines joined),
to what is done with it, in the order they run:

* `Run(shrunk)`: run the shrunk form; `writes` are globs (under the temporary folder) it must create.
* `Compose(args, reason)`: a command that cannot run here (a GPU, SLURM, hours of training, a tracker
  login) is only composed: `python -m samp.train ... --cfg job` (or `--cfg hydra`) must print its config.
* `Same(command, reason)`: what another step already runs (`make demo` is `samp.train experiment=quickstart`).
* `File(path)`: a file a page tells you to open (`rerun FILE`, `xdg-open FILE`) must exist.
* `Skip(reason)`: installs, servers, the docs build (tests/docs/) and the test suite itself.

`test_every_documented_command_is_in_the_table` (fast) fails when a page gains a command that `STEPS` does
not cover, or loses one it still lists, so a newly documented command cannot go untested.
"""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
README = REPO / "README.md"


def documented_pages() -> list[Path]:
    """README.md, then every page of the documentation site (docs/), in name order."""
    return [README, *sorted((REPO / "docs").glob("**/*.md"))]


def documented_text() -> str:
    return "\n".join(page.read_text() for page in documented_pages())


def documented_commands(text: str | None = None) -> list[str]:
    """The commands of the ```bash blocks of the README and the docs pages: continuation lines joined,
    comments and blank lines dropped, `a ; b` split, whitespace collapsed; in page order, repeats kept once."""
    text = documented_text() if text is None else text
    found = []
    for block in re.findall(r"```(?:bash|sh|shell|console)\n(.*?)```", text, re.S):
        for line in block.replace("\\\n", " ").splitlines():
            line = re.split(r"\s+#\s", line.strip())[0].strip()
            if not line or line.startswith("#"):
                continue
            found += [" ".join(part.split()) for part in line.split(" ; ")]
    return list(dict.fromkeys(found))


@dataclass
class Run:
    shrunk: str
    writes: list[str] = field(default_factory=list)
    prints: list[str] = field(default_factory=list)


@dataclass
class Compose:
    args: str
    reason: str


@dataclass
class Same:
    command: str
    reason: str = ""


@dataclass
class File:
    path: str


@dataclass
class Skip:
    reason: str


@dataclass
class RunElsewhere:
    """A command another test of the suite runs in shrunk form: `test` (a path under tests/) must hold
    `needle`, the shrunk invocation it makes."""
    test: str
    needle: str


# Shrinking: the smoke dataset (2 scenes, grids at n_e 16), four training batches of one epoch, one
# evaluation problem per split and no benchmark unless the command is about the benchmark.
TINY_SDF = "\"build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']\""
SDF_RUN = "robot_sdf_samples=tiny trainer.max_steps=40 robot_sdf_eval=tiny"
POLICY = ("datamodule.dataset=smoke datamodule.n_e=16 datamodule.val_samples=50 trainer.max_epochs=1 "
          "+trainer.limit_train_batches=4 trainer.enable_progress_bar=false evaluation.problems=1 "
          "evaluation.benchmark=null")
SWEPT = (f"{POLICY} system.robot_sdf=robot_sdf_panda_quick callbacks.eval.problems=1 callbacks.eval.every_k_epochs=1 "
         "\"hydra.sweeper.params.experiment='samp_n40,samp_n70'\"")
EVAL = "problems=1 splits=[val] benchmark=null record=false"
SWEEP = "{tmp}/runs/sweeps/anchor_size"  # documented paths under runs/ are under $SAMP_RUNS_DIR here
MEMBERS = [f"{SWEEP}/experiment=samp_n40/run.json", f"{SWEEP}/experiment=samp_n70/run.json"]
GPU = "needs a GPU"
SLURM = "needs a SLURM cluster"
LONG = "hours of training at this size; the same recipe runs shrunk in the steps above"
# Table I at the quickstart budget (docs/baselines.md) (its dataset id, the budget every method shares, SAMP's extras)
TABLE_I_DATA = "quickstart@ID"  # the id your own generate printed
TABLE_I_BUDGET = (f"datamodule.dataset={TABLE_I_DATA} trainer.max_epochs=5 system.optimizer.lr=1e-3 system.scheduler.T_0=5 "
                  "system.scheduler.T_mult=1 datamodule.val_samples=1000")
TABLE_I_SAMP = "system.robot_sdf=robot_sdf_panda_quick 'model.point_hidden=[32,64,128]' callbacks=default"
TABLE_I_LONG = "minutes of training and evaluation per member; the anchor_size sweep runs shrunk above"

STEPS: list[tuple[str, object]] = [
    # Datasets
    ("python -m samp.data generate dataset=quickstart workers=2",
     Run("python -m samp.data generate dataset=smoke workers=2", ["datasets/smoke/*/manifest.json"])),
    ("python -m samp.data generate dataset=standard workers=8",
     Run("python -m samp.data generate dataset=smoke workers=2", prints=["already generated"])),
    ("python -m samp.data ls", Run("python -m samp.data ls", prints=["smoke@"])),
    ("python -m samp.data show dataset=quickstart", Run("python -m samp.data show dataset=smoke", prints=["smoke"])),
    ("python -m samp.data verify dataset=quickstart", Run("python -m samp.data verify dataset=smoke")),
    # Sharing through remotes and pinning inputs: tests/data/test_data_remote.py runs them against a folder and
    # a local S3 API server on the smoke dataset and a tiny run
    ("python -m samp.data push dataset=quickstart remote=file:///srv/samp",
     RunElsewhere("data/test_data_remote.py", '"push", f"dataset=smoke@{ident}", f"remote={remote}"')),
    ("python -m samp.data pull dataset=quickstart@ID remote=file:///srv/samp",
     RunElsewhere("data/test_data_remote.py", '"pull", f"dataset=smoke@{ident[:6]}", f"remote={remote}"')),
    ("python -m samp.train experiment=quickstart --lock",
     RunElsewhere("data/test_data_remote.py", '"samp.train", *TRAIN, "datamodule.dataset=smoke", "--lock"')),
    ("python -m samp.runs push runs/quickstart/2026-05-01_10-00-00 remote=file:///srv/samp",
     RunElsewhere("data/test_data_remote.py", '"push", str(run), f"remote={where}"')),
    ("python -m samp.runs pull quickstart/2026-05-01_10-00-00 remote=file:///srv/samp",
     RunElsewhere("data/test_data_remote.py", '"pull", f"mpnet/{run.name}", f"remote={where}"')),
    ("python -m samp.data inspect dataset=quickstart", Run("python -m samp.data inspect dataset=smoke")),
    # Shards of a spec of its own (the smoke spec with another seed): one shard, the launcher, the merge
    ("python -m samp.data generate dataset=paper shard=3 num_shards=40 workers=8",
     Run("python -m samp.data generate dataset=smoke dataset.seed=5 dataset.name=shards shard=0 num_shards=2 "
         "progress=false", ["datasets/shards/.work/*/*.mcap"])),
    ("python -m samp.data.shards -m +dataset=standard num_shards=4 'shard=range(0,4)' hydra/launcher=shards_joblib",
     Run("python -m samp.data.shards -m +dataset=smoke dataset.seed=5 dataset.name=shards num_shards=2 "
         "'shard=range(0,2)' hydra/launcher=shards_joblib", ["datasets/shards/*/manifest.json"])),
    ("python -m samp.data merge dataset=paper",
     Run("python -m samp.data merge dataset=smoke dataset.seed=5 dataset.name=shards", prints=["already merged into"])),
    ("python -m samp.data.shards -m +dataset=paper num_shards=40 'shard=range(0,40)' workers=8 "
     "hydra/launcher=shards_slurm hydra.launcher.partition=NAME", Skip(SLURM + " (its job path runs through shards_submitit_local, below)")),
    # The demo: dataset found, the small robot SDF built, the policy trained and evaluated
    ("python -m samp.train experiment=quickstart",
     Run(f"python -m samp.train experiment=quickstart {POLICY} {TINY_SDF}",
         ["runs/quickstart/*/run.json", "runs/quickstart/*/eval/metrics.json", "runs/quickstart/*/eval/recording.rrd",
          "runs/quickstart/*/plots/summary.png", "runs/quickstart/*/metrics.csv", "runs/robot_sdf_panda_quick/*/robot_sdf.pt"],
         prints=["done: "])),
    ("make demo", Same("python -m samp.train experiment=quickstart", "the Makefile runs it after installing")),
    ("python -m samp.train experiment=robot_sdf_panda_quick",
     Same("python -m samp.train experiment=quickstart", "the demo builds it (build_missing.robot_sdf)")),
    ("rerun runs/quickstart/<timestamp>/eval/recording.rrd", File("{run}/eval/recording.rrd")),
    ("xdg-open runs/quickstart/<timestamp>/plots/summary.png", File("{run}/plots/summary.png")),
    ("python -m samp.runs show runs/quickstart/<timestamp>", Run("python -m samp.runs show {run}", prints=["protocol"])),
    ("python examples/plan.py runs/quickstart/<timestamp> [SEED]",
     Run("python {repo}/examples/plan.py {run} 3", prints=[" steps: "])),
    # The other examples (each also run with checks of its own by tests/examples/)
    ("python examples/scene_and_grid.py --generator shelf --seed 3 --n-e 12 --out out",
     Run("python {repo}/examples/scene_and_grid.py --generator shelf --seed 3 --n-e 12 --out {tmp}/out",
         ["out/scene.json", "out/grid.npy"])),
    ("python examples/evaluate_run.py straight --benchmark smoke",
     Run("python {repo}/examples/evaluate_run.py straight --benchmark smoke", prints=["success"])),
    ("python examples/evaluate_run.py runs/quickstart/<timestamp> --benchmark smoke --problems 4",
     Run("python {repo}/examples/evaluate_run.py {run} --benchmark smoke --problems 4", prints=["success"])),
    ("python examples/cloud_to_grid.py --n-e 16 --out /tmp/cloud",
     Run("python {repo}/examples/cloud_to_grid.py --n-e 16 --out {tmp}/cloud", ["cloud/cloud.pcd", "cloud/grid.npy"])),
    ("python examples/cloud_to_grid.py --cloud /tmp/cloud/cloud.pcd --origin 1.9 0 1.3 --n-e 16",
     Run("python {repo}/examples/cloud_to_grid.py --cloud {tmp}/cloud/cloud.pcd --origin 1.9 0 1.3 --n-e 16 "
         "--out {tmp}/cloud2", ["cloud2/grid.npy"])),
    # Robot SDFs: the hash grid, then the NN-SDF baseline under the same name
    ("python -m samp.train experiment=robot_sdf_panda",
     Run(f"python -m samp.train experiment=robot_sdf_panda {SDF_RUN}", ["runs/robot_sdf_panda/*/robot_sdf.pt"])),
    ("python -m samp.train experiment=robot_sdf_panda model=robot_sdf_nn",
     Run(f"python -m samp.train experiment=robot_sdf_panda model=robot_sdf_nn {SDF_RUN}")),
    ("python -m samp.train experiment=robot_sdf_iiwa", Compose("experiment=robot_sdf_iiwa", "another robot's "
                                                              "samples; the recipe runs above for the panda")),
    ("python tools/bench.py robot_sdf",
     Run("python {repo}/tools/bench.py robot_sdf --sdf-eval tiny --override robot_sdf_samples=tiny trainer.max_steps=40",
         ["runs/robot_sdf_compare_panda/*/robot_sdf_table.md", "runs/robot_sdf_compare_panda/*/robot_sdf_nn/robot_sdf.pt"])),
    # Policies that cannot run here, composed
    ("python -m samp.train experiment=samp_n100 datamodule.dataset=standard trainer=gpu",
     Compose("experiment=samp_n100 datamodule.dataset=standard trainer=gpu", GPU)),
    ("python -m samp.train experiment=samp_n100 trainer=gpu datamodule.dataset=paper",
     Compose("experiment=samp_n100 trainer=gpu datamodule.dataset=paper", GPU)),
    ("python -m samp.train experiment=samp_n40", Same("python -m samp.train -m sweep=anchor_size hydra/launcher="
                                                      "runs_joblib hydra.launcher.n_jobs=2", "its first member")),
    ("python -m samp.train experiment=samp_no_coll_loss", Compose("experiment=samp_no_coll_loss", LONG)),
    ("python -m samp.train experiment=samp_cpu", Compose("experiment=samp_cpu", LONG)),
    ("python -m samp.train -m sweep=data_scaling", Compose("-m sweep=data_scaling", LONG)),
    ("python -m samp.train -m sweep=recipe_seeds", Compose("-m sweep=recipe_seeds", LONG)),
    ("python -m samp.train -m sweep=loss_terms", Compose("-m sweep=loss_terms", LONG)),
    ("python -m samp.train experiment=samp_cpu loss=paper", Compose("experiment=samp_cpu loss=paper", LONG)),
    ("SAMP_TRACKING_URI=http://mlflow.example.org:5000 python -m samp.train experiment=samp_n100",
     RunElsewhere("runs/test_runs_tracking.py", 'env={"SAMP_TRACKING_URI": rest.url}')),
    ("python -m samp.train experiment=samp_n100 tracking.uri=off", Compose("experiment=samp_n100 tracking.uri=off", LONG)),
    ("python -m samp.train experiment=samp_n100 logger=tensorboard",
     RunElsewhere("runs/test_runs_tracking.py", '"logger=tensorboard"')),
    ("tensorboard --logdir runs/samp_n100", RunElsewhere("runs/test_runs_tracking.py", "EventAccumulator(str(folder")),
    ("python -m samp.train experiment=samp_n100 'logger=[tensorboard,wandb]'",
     Compose("experiment=samp_n100 'logger=[tensorboard,wandb]'", LONG)),
    ("python -m samp.train experiment=samp_n100 logger=wandb", Compose("experiment=samp_n100 logger=wandb", LONG)),
    ("python -m samp.train experiment=mpinet [trainer=gpu] [datamodule.dataset=NAME@ID]",
     Compose("experiment=mpinet", "tests/policy/test_baselines_cli.py trains and evaluates it shrunk")),
    ("python -m samp.train experiment=mpnet [trainer=gpu] [datamodule.dataset=NAME@ID]",
     Compose("experiment=mpnet", "tests/policy/test_baselines_cli.py trains and evaluates it shrunk")),
    ("python -m samp.train experiment=simpnet [trainer=gpu] [datamodule.dataset=NAME@ID]",
     Compose("experiment=simpnet", "tests/policy/test_baselines_cli.py trains and evaluates it shrunk")),
    ("python -m samp.train experiment=mpinet model=mpinet_paper trainer=gpu",
     Compose("experiment=mpinet model=mpinet_paper trainer=gpu", GPU)),
    # Our Table I at the quickstart budget: the paper_table_1 sweep, its members named on the command line
    ("python -m samp.data generate dataset=quickstart 'dataset.resolutions=[40,100,160]' workers=1",
     Same("python -m samp.data generate dataset=quickstart workers=2", "the same spec with grids at n_e 160 too")),
    (f"python -m samp.train -m sweep=paper_table_1 experiment=samp_n100 {TABLE_I_BUDGET} {TABLE_I_SAMP}",
     Compose(f"-m sweep=paper_table_1 experiment=samp_n100 {TABLE_I_BUDGET} {TABLE_I_SAMP}", TABLE_I_LONG)),
    (f"python -m samp.train -m sweep=paper_table_1 experiment=mpnet,simpnet,mpinet {TABLE_I_BUDGET}",
     Compose(f"-m sweep=paper_table_1 experiment=mpnet,simpnet,mpinet {TABLE_I_BUDGET}", TABLE_I_LONG)),
    (f"python -m samp.eval planner=expert_raw dataset={TABLE_I_DATA}",
     Same("python -m samp.eval planner=expert_raw dataset=REF", "on the dataset of the Table I runs")),
    (f"python -m samp.eval planner=ompl_sampling dataset={TABLE_I_DATA}",
     Same("python -m samp.eval planner=ompl_sampling dataset=REF", "on the dataset of the Table I runs")),
    (f"python -m samp.train -m sweep=paper_table_1 experiment=samp_n160 {TABLE_I_BUDGET} {TABLE_I_SAMP}",
     Compose(f"-m sweep=paper_table_1 experiment=samp_n160 {TABLE_I_BUDGET} {TABLE_I_SAMP}", TABLE_I_LONG)),
    # Evaluation of the demo's run
    ("python -m samp.eval run=runs/mpinet/TIMESTAMP overwrite=true",
     Run(f"python -m samp.eval run={{run}} overwrite=true {EVAL}", ["{run}/eval/metrics.json"])),
    ("python -m samp.eval run=runs/EXP/TIME",
     Run(f"python -m samp.eval run={{run}} {EVAL}", ["{run}/eval-2/metrics.json"], ["earlier evaluation, kept"])),
    ("python -m samp.eval run=runs/samp_n100/<timestamp>", Same("python -m samp.eval run=runs/EXP/TIME", "any run")),
    ("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=unseen out=/tmp/bench",
     Run("python -m samp.eval run={run} splits=[] benchmark=smoke benchmark_problems=2 record=false out={tmp}/bench",
         ["bench/metrics.json", "datasets/bench_smoke/*/manifest.json"])),
    ("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=confirm out=/tmp/confirm",
     Same("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=unseen out=/tmp/bench",
          "another benchmark spec by name (tests/data/test_data_detours.py checks it is bench_unseen's recipe)")),
    ("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=worlds out=/tmp/worlds",  # scenes from world files
     Run("python -m samp.eval run={run} splits=[] benchmark=worlds benchmark_problems=2 record=false out={tmp}/worlds",
         ["worlds/metrics.json", "datasets/bench_worlds/*/manifest.json"], ["benchmark_file"])),
    ("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=hard out=/tmp/hard",
     Same("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=unseen out=/tmp/bench",
          "another benchmark spec by name (tests/data/test_data_detours.py checks bench_hard's spec, "
          "tests/eval/test_eval_protocol.py its all-hard section)")),
    ("python -m samp.train experiment=quickstart dagger.rounds=1",
     RunElsewhere("train/test_dagger_stage.py", '"dagger.rounds=1", "dagger.per_scene=3"')),
    ("python -m samp.train experiment=samp_cpu dagger.teacher=runs/samp_cpu/TIME",
     RunElsewhere("train/test_dagger_stage.py", 'f"dagger.teacher={staged[\'teacher\']}"')),
    ("python -m samp.train.adapt from=runs/samp_cpu/TIME cells=my_cells/",
     RunElsewhere("train/test_adapt.py", '"-m", "samp.train.adapt"')),
    ("python -m samp.eval run=runs/EXP/TIME splits=[] benchmark=hard stride=2 out=/tmp/stride2",
     Run(f"python -m samp.eval run={{run}} stride=2 out={{tmp}}/stride2 {EVAL}", ["stride2/metrics.json"])),
    ("python -m samp.eval run=runs/EXP/TIME check=8 out=/tmp/check",
     Run(f"python -m samp.eval run={{run}} check=2 out={{tmp}}/check {EVAL}", ["check/metrics.json"], ["samp+check"])),
    ("python -m samp.eval run=runs/EXP/TIME 'check={candidates:8,noisy:4}' out=/tmp/noisy",
     Run(f"python -m samp.eval run={{run}} 'check={{{{candidates:2,noisy:1}}}}' out={{tmp}}/noisy {EVAL}",
         ["noisy/metrics.json"], ["samp+check"])),
    ("python -m samp.eval planner=expert dataset=quickstart",
     Run(f"python -m samp.eval planner=expert dataset=smoke {EVAL}", ["runs/eval/expert_smoke@*/metrics.json"])),
    ("python -m samp.eval planner=straight dataset=quickstart benchmark=null",
     Run(f"python -m samp.eval planner=straight dataset=smoke {EVAL}", ["runs/eval/straight_smoke@*/metrics.json"])),
    ("python -m samp.eval planner=expert_raw dataset=REF",
     Run(f"python -m samp.eval planner=expert_raw dataset=smoke {EVAL}", ["runs/eval/expert_raw_smoke@*/metrics.json"])),
    ("python -m samp.eval planner=ompl_sampling dataset=REF",
     Run(f"python -m samp.eval planner=ompl_sampling dataset=smoke {EVAL}",
         ["runs/eval/ompl_sampling_smoke@*/metrics.json"])),
    ("python -m samp.eval run=runs/EXP/TIME dataset=other allow_other_dataset=true splits=[val] benchmark=null",
     RunElsewhere("eval/test_eval_binding.py", '"allow_other_dataset=true"')),
    ("python -m samp.eval run=runs/EXP/TIME grid_source=reconstructed out=/tmp/recon",
     Run(f"python -m samp.eval run={{run}} grid_source=reconstructed out={{tmp}}/recon {EVAL}", ["recon/metrics.json"])),
    ("python -m samp.eval run=runs/samp_n100/<timestamp> grid_source=reconstructed out=/tmp/recon",
     Same("python -m samp.eval run=runs/EXP/TIME grid_source=reconstructed out=/tmp/recon", "any run folder")),
    ("python -m samp.eval run=runs/EXP/TIME grid_source=reconstructed camera=single unknown=occupied out=/tmp/recon1",
     Run(f"python -m samp.eval run={{run}} grid_source=reconstructed camera=single unknown=occupied "
         f"out={{tmp}}/recon1 {EVAL}", ["recon1/metrics.json"])),
    ("python -m samp.eval run=runs/EXP/TIME grid_source=reconstructed camera=path/to/my_cameras.yaml out=/tmp/recon2",
     Run(f"python -m samp.eval run={{run}} grid_source=reconstructed camera={{tmp}}/path/to/my_cameras.yaml "
         f"out={{tmp}}/recon2 {EVAL}", ["recon2/metrics.json"])),
    # Resuming the demo's run for one more epoch; the other spellings composed
    ("python -m samp.train resume=runs/samp_n100/2026-05-01_10-00-00 trainer.max_epochs=200",
     Compose("resume={run} trainer.max_epochs=200", "tests/runs/test_runs_resume.py interrupts a run and resumes it")),
    ("python -m samp.train resume=runs/samp_n100/2026-05-01_10-00-00",
     Compose("resume={run}", "as above")),
    ("python -m samp.train resume=runs/samp_n100/<timestamp>", Compose("resume={run}", "as above")),
    ("python -m samp.train experiment=samp_n100 resume=runs/samp_n100/<timestamp>",
     Compose("experiment=samp_n100 resume={run}", "as above")),
    # A two-member sweep through joblib, run again with the basic launcher (both members skipped)
    ("python -m samp.train -m sweep=anchor_size hydra/launcher=runs_joblib hydra.launcher.n_jobs=2",
     Run(f"python -m samp.train -m sweep=anchor_size hydra/launcher=runs_joblib hydra.launcher.n_jobs=2 {SWEPT}",
         MEMBERS + [f"{SWEEP}/experiment=samp_n40/eval/metrics.json"])),
    ("python -m samp.train -m sweep=anchor_size",
     Run(f"python -m samp.train -m sweep=anchor_size {SWEPT}", prints=["completed earlier, skipped"])),
    ("python -m samp.train -m sweep=anchor_size hydra/launcher=runs_joblib",
     Same("python -m samp.train -m sweep=anchor_size hydra/launcher=runs_joblib hydra.launcher.n_jobs=2")),
    ("python -m samp.train -m sweep=loss_ablation", Compose("-m sweep=loss_ablation", LONG)),
    ("python -m samp.train -m experiment=samp_n40,samp_n70 seed=0,1,2",
     Compose("-m experiment=samp_n40,samp_n70 seed=0,1,2", "six trainings; the sweep above runs two")),
    ("python -m samp.train -m sweep=anchor_size trainer=gpu hydra/launcher=runs_slurm hydra.launcher.partition=gpu",
     Compose("-m sweep=anchor_size trainer=gpu hydra/launcher=runs_slurm hydra.launcher.partition=gpu --cfg hydra",
             SLURM)),
    ("python -m samp.train -m sweep=anchor_size trainer=ddp hydra/launcher=runs_slurm hydra.launcher.partition=gpu",
     Compose("-m sweep=anchor_size trainer=ddp hydra/launcher=runs_slurm hydra.launcher.partition=gpu --cfg hydra",
             SLURM)),
    ("python -m samp.train -m sweep=anchor_size trainer=ddp trainer.devices=4 hydra/launcher=runs_slurm "
     "hydra.launcher.tasks_per_node=4 hydra.launcher.gpus_per_node=4",
     Compose("-m sweep=anchor_size trainer=ddp trainer.devices=4 hydra/launcher=runs_slurm "
             "hydra.launcher.tasks_per_node=4 hydra.launcher.gpus_per_node=4 --cfg hydra", SLURM)),
    # Looking at runs
    ("python -m samp.runs ls", Run("python -m samp.runs ls", prints=["quickstart"])),
    ("python -m samp.runs ls experiment=samp_n100 status=completed keys=eval/samp/benchmark/success_rate",
     Run("python -m samp.runs ls experiment=quickstart status=completed keys=eval/samp/val/success_rate",
         prints=["1 run(s)"])),
    ("python -m samp.runs ls protocol=1", Run("python -m samp.runs ls protocol=1")),
    ("python -m samp.runs show runs/samp_n100/2026-05-01_10-00-00",
     Run(f"python -m samp.runs show {SWEEP}/experiment=samp_n40", prints=["experiment=samp_n40"])),
    ("python -m samp.runs compare RUN_A RUN_B",
     Run(f"python -m samp.runs compare {SWEEP}/experiment=samp_n40 {SWEEP}/experiment=samp_n70")),
    ("python -m samp.runs table runs/sweeps/anchor_size by=datamodule.n_e metrics=eval/samp/benchmark/success_rate,"
     "eval/samp/benchmark_hard/success_rate,eval/samp/benchmark/collision_rate",
     Run(f"python -m samp.runs table {SWEEP} by=datamodule.n_e metrics=eval/samp/val/success_rate,"
         "eval/samp/val/collision_rate", [f"{SWEEP}/table_by_datamodule.n_e.md", f"{SWEEP}/table_by_datamodule.n_e.csv"],
         ["| 16 | 2 | completed |"])),
    ("python -m samp.runs plot runs/sweeps/anchor_size by=datamodule.n_e",
     Run(f"python -m samp.runs plot {SWEEP} by=datamodule.n_e", [f"{SWEEP}/*.png"])),
    ("python -m samp.runs plot runs/sweeps/loss_ablation by=name kind=bars metrics=eval/samp/benchmark/success_rate",
     Run(f"python -m samp.runs plot {SWEEP} by=name kind=bars metrics=eval/samp/val/success_rate", [f"{SWEEP}/*.png"])),
    ("python -m samp.runs paper-tables", Run("python -m samp.runs paper-tables", ["runs/paper_tables/table_1.md"])),
    # Robots and scenes
    ("python -m samp.robot show robot=panda [out=FILE.rrd] [configs=4] [seed=0]",
     Run("python -m samp.robot show robot=panda configs=1", ["runs/robot/panda/robot.rrd"])),
    ("rerun runs/robot/panda/robot.rrd", File("{tmp}/runs/robot/panda/robot.rrd")),
    ("python tools/self_collision_pairs.py panda --samples 2000",
     Run("python {repo}/tools/self_collision_pairs.py panda --samples 50")),
    ("python -m samp.robot add urdf=path/to/myarm.urdf name=myarm [base=LINK] [ee=LINK] [out=DIR] [samples=1000] [seed=0]",
     RunElsewhere("robot/test_robot_add.py", '"samp.robot", "add", f"urdf={urdf}", "name=toyarm"')),
    ("python -m samp.robot show robot=myarm", RunElsewhere("robot/test_robot_add.py", '"samp.robot", "show", "robot=toyarm"')),
    ("python -m samp.train experiment=robot_sdf_quick robot=myarm",
     RunElsewhere("robot/test_robot_add.py", '"samp.train", "experiment=robot_sdf_quick", "robot=toyarm"')),
    ("python -m samp.data generate dataset=smoke dataset.robot=myarm dataset.name=myarm_smoke",
     RunElsewhere("robot/test_robot_add.py", '"dataset=smoke", "dataset.robot=toyarm", "dataset.name=toyarm_smoke"')),
    ("python -m samp.train experiment=quickstart robot=myarm datamodule.dataset=myarm_smoke evaluation.benchmark=null",
     RunElsewhere("robot/test_robot_add.py", '"experiment=quickstart", "robot=toyarm", "datamodule.dataset=toyarm_smoke"')),
    ("python -m samp.scene show scene=tabletop seed=3 n_e=64",
     Run("python -m samp.scene show scene=tabletop seed=3 n_e=16", ["runs/scene/tabletop_3/scene.rrd"])),
    ("python -m samp.scene show file=examples/worlds/cubby.yaml",
     Run("python -m samp.scene show file=examples/worlds/cubby.yaml n_e=16", ["runs/scene/file_cubby/scene.rrd"],
         ["from file cubby.yaml (world)"])),
    # The training entry point's own help and a composed config; a second demo run to compare with
    ("python -m samp.train --help", Run("python -m samp.train --help", prints=["experiment", "sweep"])),
    ("python -m samp.train experiment=quickstart --cfg job",
     Run("python -m samp.train experiment=quickstart --cfg job", prints=["name: quickstart"])),
    ("python -m samp.train experiment=quickstart seed=1",
     Compose("experiment=quickstart seed=1", "a second demo run, the same recipe as the first (run above)")),
    # Not run here
    ("make docs", Skip("mkdocs build --strict, run by tests/docs/test_docs_build.py")),
    ("make docs-serve", Skip("starts a web server")),
    ("make test", Skip("the test suite itself")),
    ("make test-fast", Skip("the test suite itself")),
    ("make install", Skip("installs packages")),
    ("make bench", Skip("the robot suite; tests/tools/test_bench_cli.py runs every suite at tiny settings")),
    ("python tools/bench.py baselines [--runs RUN ...]",
     Run("python {repo}/tools/bench.py baselines --baseline-problems 1", prints=["mpinet", "simpnet"])),
    ("python -m samp.train -m sweep=paper_table_1 trainer=gpu", Compose("-m sweep=paper_table_1 trainer=gpu", GPU)),
    ("python -m samp.train -m sweep=anchor_size trainer=gpu", Compose("-m sweep=anchor_size trainer=gpu --cfg hydra", GPU)),
    ("python -m samp.train -m sweep=loss_ablation trainer=gpu",
     Compose("-m sweep=loss_ablation trainer=gpu --cfg hydra", GPU)),
    # Benchmarks: tests/tools/test_bench_cli.py runs every suite end to end at tiny settings
    ("python tools/bench.py perception", RunElsewhere("tools/test_bench_cli.py", '"perception": ["--anchors", "8"]')),
    ("python tools/bench.py perception --run runs/EXP/TIME",
     Run("python {repo}/tools/bench.py perception --anchors 8 --run {run} --dataset smoke", prints=["success"])),
    ("python tools/bench.py data", RunElsewhere("tools/test_bench_cli.py", '"data": ["--workers", "1"')),
    ("python tools/bench.py policy --anchors 40 100 160 --robot-sdf ARTIFACT",
     RunElsewhere("tools/test_bench_cli.py", '"policy": ["--anchors", "8"]')),
    ("python tools/bench.py policy --policy-run RUN --baseline-src DIR",
     Skip("needs a second checkout (a git worktree of another commit) and a trained run")),
    # The step's options on the demo's run (each a further evaluation, eval-N/)
    ("python -m samp.eval run=RUN robot_sdf_pairs=all", Run(f"python -m samp.eval run={{run}} robot_sdf_pairs=all {EVAL}")),
    ("python -m samp.eval run=RUN compiled=false", Run(f"python -m samp.eval run={{run}} compiled=false {EVAL}")),
    # Scale-out: DDP on CPUs, SLURM's job path on one machine, the paper-scale recipe and the GPU check
    ("python -m samp.train experiment=quickstart trainer=ddp trainer.accelerator=cpu trainer.devices=2",
     RunElsewhere("train/test_ddp.py", 'DDP = ["trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2"]')),
    ("python -m samp.train -m sweep=anchor_size hydra/launcher=runs_submitit_local",
     RunElsewhere("runs/test_runs_submitit.py", '"hydra/launcher=runs_submitit_local"')),
    ("python -m samp.data.shards -m +dataset=standard num_shards=4 'shard=range(0,4)' hydra/launcher=shards_submitit_local",
     RunElsewhere("data/test_data_shards_submitit.py", '"hydra/launcher=shards_submitit_local"')),
    ("python -m samp.train experiment=robot_sdf_panda_paper trainer=gpu",
     Compose("experiment=robot_sdf_panda_paper trainer=gpu", GPU)),
    ("python -m samp.train experiment=samp_paper trainer=gpu", Compose("experiment=samp_paper trainer=gpu", GPU)),
    ("python -m samp.train experiment=samp_paper_ours trainer=gpu", Compose("experiment=samp_paper_ours trainer=gpu", GPU)),
    ("python tools/bench.py paper", RunElsewhere("tools/test_bench_cli.py", '"paper": ["--steps", "1"')),
    ("bash tools/gpu_check.sh runs/gpu_check",
     Skip("needs a GPU; tests/tools/test_gpu_check.py checks that it parses and refuses without one")),
    ("python tools/bench.py -h", Run("python {repo}/tools/bench.py -h", prints=["robot", "policy"])),
    ("python tools/mutants.py --list", Run("python {repo}/tools/mutants.py --list")),
    ("pip install -e '.[mlflow]'", Skip("installs packages")),
    ("pip install -e '.[wandb]'", Skip("installs packages")),
    ("mlflow ui --backend-store-uri sqlite:///runs/mlflow.db",
     RunElsewhere("runs/test_runs_tracking.py", '"server", "--backend-store-uri", f"sqlite:///{runs}/mlflow.db"')),
    # Bring your own (docs/bring-your-own.md): from an installed wheel, in a project folder of its own
    ("pip install /path/to/samp", Skip("installs; tests/e2e/test_bring_your_own.py builds and installs the wheel")),
    ("pip install '/path/to/samp[import]'", Skip("installs; the dev extra includes [import]")),
    ("export SAMP_CONFIG_PATH=$PWD/conf",
     RunElsewhere("e2e/test_bring_your_own.py", '"SAMP_CONFIG_PATH": str(project / "conf")')),
    ("samp-robot add urdf=robots/myarm/myarm.urdf name=myarm",
     RunElsewhere("e2e/test_bring_your_own.py", "samp-robot add urdf=robots/franka_panda/panda.urdf name=myarm")),
    ("samp-data import source=demos.npz name=mydemos robot=myarm",
     RunElsewhere("e2e/test_bring_your_own.py", "samp-data import source=demos.npz name=mydemos robot=myarm")),
    ("samp-train experiment=my_policy", RunElsewhere("e2e/test_bring_your_own.py", "samp-train experiment=my_policy {TINY}")),
    ("samp-eval run=runs/my_policy/TIME", RunElsewhere("e2e/test_bring_your_own.py", "samp-eval run={runs[0].parent}")),
    ("samp-train experiment=my_policy seed=1",
     RunElsewhere("e2e/test_bring_your_own.py", "samp-train experiment=my_policy seed=1 {TINY}")),
    ("samp-runs compare runs/my_policy/TIME_A runs/my_policy/TIME_B",
     RunElsewhere("e2e/test_bring_your_own.py", "samp-runs compare {runs[0].parent} {runs[1].parent}")),
    ("python -m samp.data import source=demos.npz name=mydemos scene=scenes/cell_a.json",
     RunElsewhere("data/test_data_import.py", "python -m samp.data import source=demos.npz name=mydemos scene=")),
]

# The camera set docs/perception.md shows as a YAML example, used by the `camera=path/to/my_cameras.yaml` step.
CAMERA_YAML = re.compile(r"```yaml\n(_target_: samp.sim.camera.camera_set.*?)```", re.S)


def test_every_documented_command_is_in_the_table():
    documented, covered = documented_commands(), [c for c, _ in STEPS]
    assert len(covered) == len(set(covered)), "a command is listed twice in STEPS"
    missing = [c for c in documented if c not in covered]
    assert not missing, "commands of README.md or docs/ with no entry in tests/test_readme.py STEPS (add how to run them shrunk):\n" \
        + "\n".join(missing)
    stale = [c for c in covered if c not in documented]
    assert not stale, "STEPS lists commands that neither README.md nor docs/ has:\n" + "\n".join(stale)
    steps = dict(STEPS)
    for command, step in STEPS:
        if isinstance(step, Same):
            assert isinstance(steps.get(step.command), Run), f"{command!r} is the same as {step.command!r}, not run"
        if isinstance(step, RunElsewhere):
            test = REPO / "tests" / step.test
            assert test.is_file() and step.needle in test.read_text(), f"{command!r}: {test} does not run {step.needle}"
    for example in sorted((REPO / "examples").glob("*.py")):  # examples are documented commands like any other
        assert any(f"examples/{example.name}" in c for c in documented), f"no page runs a command of {example}"


def test_command_extraction():
    text = "x\n```bash\npython -m a b=1   # a comment\n# only a comment\npython -m c \\\n    d=2 ; python -m e\n```\n"
    assert documented_commands(text) == ["python -m a b=1", "python -m c d=2", "python -m e"]


def _snapshot(root: Path) -> dict[str, int]:
    """Every file of the repository tree with its mtime, caches and the git folder left out."""
    skip = {"__pycache__", ".pytest_cache", ".git", ".venv", ".ruff_cache", ".mypy_cache"}
    out = {}
    for dirpath, dirnames, filenames in os.walk(root):
        dirnames[:] = [d for d in dirnames if d not in skip and not d.endswith(".egg-info")]
        for name in filenames:
            path = Path(dirpath) / name
            out[str(path.relative_to(root))] = path.stat().st_mtime_ns
    return out


class _Runner:
    def __init__(self, tmp: Path, monkeypatch):
        self.tmp, self.work, self.monkeypatch = tmp, tmp / "work", monkeypatch
        self.work.mkdir()
        self.env = {**os.environ, "SAMP_RUNS_DIR": str(tmp / "runs"), "SAMP_DATASETS_DIR": str(tmp / "datasets"),
                    "SAMP_CACHE_DIR": str(tmp / "cache"), "OMP_NUM_THREADS": "1", "RERUN_ANALYTICS": "0",
                    "PYTHONPATH": str(REPO)}
        self.failures: list[str] = []
        self.times: list[tuple[float, str]] = []

    def fields(self) -> dict[str, str]:
        runs = sorted((self.tmp / "runs" / "quickstart").glob("*/"))
        return {"tmp": str(self.tmp), "repo": str(REPO), "run": str(runs[0]) if runs else "<no quickstart run yet>"}

    def _argv(self, shrunk: str) -> list[str]:
        argv = shlex.split(shrunk.format(**self.fields()))
        if argv[0] in ("python", "python3"):
            argv[0] = sys.executable
        return argv

    def _call(self, argv: list[str], timeout: int = 900) -> tuple[int, str, str]:
        """(exit code, stdout, stderr) of `argv`. The quick read-only entry points (listing, showing,
        composing) run in this process, with the same environment and working folder: a Python start
        with torch costs seconds each; everything that trains, plans or evaluates runs as a subprocess."""
        module = argv[2] if argv[1:2] == ["-m"] else None
        quick = module == "samp.runs" or (module == "samp.data" and argv[3] in ("ls", "show", "verify", "inspect")) \
            or (module == "samp.train" and any(a.startswith("--cfg") or a in ("--help", "-h") for a in argv))
        if not quick:
            out = subprocess.run(argv, cwd=self.work, env=self.env, capture_output=True, text=True, timeout=timeout)
            return out.returncode, out.stdout, out.stderr
        import contextlib
        import importlib
        import io

        main = importlib.import_module(f"{module}.__main__" if module != "samp.train" else "samp.train.cli").main
        stdout, stderr = io.StringIO(), io.StringIO()
        with self.monkeypatch.context() as mp:
            for key in ("SAMP_RUNS_DIR", "SAMP_DATASETS_DIR", "SAMP_CACHE_DIR"):
                mp.setenv(key, self.env[key])
            mp.chdir(self.work)
            with contextlib.redirect_stdout(stdout), contextlib.redirect_stderr(stderr):
                try:
                    code = main(argv[3:])
                except SystemExit as err:
                    code = err.code
        return int(code or 0), stdout.getvalue(), stderr.getvalue()

    def run(self, command: str, step) -> None:
        start = time.perf_counter()
        if isinstance(step, Run):
            argv = self._argv(step.shrunk)
            code, stdout, stderr = self._call(argv)
            text = stdout + stderr
            if code != 0:
                self.failures.append(f"{command}\n  ran {shlex.join(argv)}\n  exit {code}: {text[-1500:]}")
            for pattern in step.writes:
                pattern = pattern.format(**self.fields())
                base, pattern = (Path("/"), pattern[1:]) if pattern.startswith("/") else (self.tmp, pattern)
                if not list(base.glob(pattern)):
                    self.failures.append(f"{command}\n  wrote no {base / pattern}")
            for needle in step.prints:
                if needle not in text:
                    self.failures.append(f"{command}\n  did not print {needle!r}: {text[-1000:]}")
        elif isinstance(step, Compose):
            args = self._argv("python -m samp.train " + step.args)
            if "--cfg" not in args:
                args.append("--cfg=job")
            code, stdout, stderr = self._call(args, timeout=300)
            if code != 0 or not stdout.strip():
                self.failures.append(f"{command} ({step.reason}) does not compose:\n  {stderr[-1500:]}")
        elif isinstance(step, File):
            path = Path(step.path.format(**self.fields()))
            if not path.is_file():
                self.failures.append(f"{command}: the docs point at {path}, which does not exist")
        self.times.append((time.perf_counter() - start, command))


@pytest.mark.slow
def test_every_readme_command_works_where_it_says(tmp_path, monkeypatch):
    """Every step of STEPS in order; the repository tree is unchanged afterwards and everything written
    lies under the temporary folder's documented places."""
    runner = _Runner(tmp_path, monkeypatch)
    cameras = CAMERA_YAML.search(documented_text())
    assert cameras, "the camera-set YAML example of docs/perception.md is gone"
    (tmp_path / "path" / "to").mkdir(parents=True)
    (tmp_path / "path" / "to" / "my_cameras.yaml").write_text(cameras.group(1))
    before = _snapshot(REPO)
    for command, step in STEPS:
        runner.run(command, step)
    print("\n".join(f"{s:7.1f} s  {c}" for s, c in sorted(runner.times, reverse=True)[:12]))
    assert not runner.failures, f"{len(runner.failures)} documented command(s) failed:\n\n" + "\n\n".join(runner.failures)
    after = _snapshot(REPO)
    changed = sorted(k for k in set(before) | set(after) if before.get(k) != after.get(k))
    assert not changed, f"documented commands wrote into the repository: {changed[:20]}"
    written = sorted(p.name for p in tmp_path.iterdir())
    assert set(written) <= {"work", "runs", "datasets", "cache", "bench", "check", "noisy", "stride2", "recon", "recon1",
                            "recon2", "path", "out", "cloud", "cloud2", "worlds"}, written
    assert not any((tmp_path / "work").iterdir()), f"written into the working folder: {list((tmp_path / 'work').iterdir())}"
    # The NN-SDF run made under the name robot_sdf_panda after the hash grid's is not what the name means.
    from samp.train.prerequisites import resolve_robot_sdf

    runs = sorted((tmp_path / "runs" / "robot_sdf_panda").glob("*/"))
    assert len(runs) == 2 and resolve_robot_sdf("robot_sdf_panda", tmp_path / "runs") == runs[0]
