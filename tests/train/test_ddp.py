"""Data-parallel training, run for real: `trainer=ddp trainer.accelerator=cpu trainer.devices=2` starts two
processes that talk over gloo, as Lightning's own CI tests DDP on CPUs.

For the policy, against a single process training on batches of twice the size (the same seed): each
rank draws a disjoint part of every global batch (recorded with `datamodule.record_draws=true`), the two
parts together are the single process's batch, the logged training loss (the mean over the ranks) is the
single process's at every step, and so are the weights at the end; the run folder, its metrics, its
checkpoints and the in-training evaluation are written once, by rank 0; `resume=` of the DDP run goes on
in the same folder. For the robot SDF: the ranks draw different samples, the artifact is written once,
and resuming goes on."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import torch

pytestmark = pytest.mark.slow

DDP = ["trainer=ddp", "trainer.accelerator=cpu", "trainer.devices=2"]
TINY_SDF = "build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']"
# the smoke dataset, plain random batches without noise (so that one process can draw the same global
# batches), the rollout evaluation after every epoch on one problem, a line in metrics.csv per step
POLICY = ["experiment=quickstart", "datamodule.dataset=smoke", "datamodule.n_e=16", "datamodule.val_samples=20",
          "datamodule.scenes_per_batch=0", "datamodule.noise=0", "datamodule.record_draws=true", "trainer.max_epochs=1",
          "+trainer.limit_train_batches=4", "trainer.log_every_n_steps=1", "trainer.enable_progress_bar=false",
          "callbacks=eval", "callbacks.eval.problems=1", "callbacks.eval.every_k_epochs=1", "evaluation.problems=1",
          "evaluation.benchmark=null", "system.optimizer.lr=1e-4", TINY_SDF]
PER_RANK = 10  # samples per rank and step; the single process takes both ranks' worth


def _cli(args: list[str], runs: Path, datasets: Path, cwd: Path) -> subprocess.CompletedProcess:
    env = {**os.environ, "SAMP_RUNS_DIR": str(runs), "SAMP_DATASETS_DIR": str(datasets), "RERUN_ANALYTICS": "0",
           "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-m", "samp.train", *args], capture_output=True, text=True, env=env,
                         cwd=cwd, timeout=900)
    assert out.returncode == 0, f"samp.train {' '.join(args)} failed:\n{out.stdout[-3000:]}\n{out.stderr[-5000:]}"
    return out


def _draws(run: Path, rank: int) -> list[dict]:
    return [json.loads(line) for line in (run / "draws" / f"rank{rank}.jsonl").read_text().splitlines()]


def _metric_rows(run: Path, key: str) -> list[tuple[int, float]]:
    with open(run / "metrics.csv") as f:
        return [(int(r["step"]), float(r[key])) for r in csv.DictReader(f) if r.get(key)]


def _weights(run: Path) -> dict[str, torch.Tensor]:
    ckpt = torch.load(run / "checkpoints" / "last.ckpt", map_location="cpu", weights_only=False)
    return {k: v for k, v in ckpt["state_dict"].items() if k.startswith("net.")}


@pytest.fixture(scope="module")
def runs(tmp_path_factory, _isolated_cache):
    """The DDP run, the single-process run on doubled batches, and the DDP run resumed for one more epoch."""
    tmp = tmp_path_factory.mktemp("ddp")
    datasets, work = tmp / "datasets", tmp / "work"
    work.mkdir()
    # one runs folder, so that the single process finds the robot SDF the first run built (the same weights)
    ddp_out = _cli([*POLICY, *DDP, f"datamodule.batch_size={PER_RANK}"], tmp / "runs", datasets, work)
    single_out = _cli([*POLICY, f"datamodule.batch_size={2 * PER_RANK}", "name=single"], tmp / "runs", datasets, work)
    (ddp,) = (tmp / "runs" / "quickstart").iterdir()
    (single,) = (tmp / "runs" / "single").iterdir()
    before = json.loads((ddp / "run.json").read_text())
    weights_before = _weights(ddp)
    resumed = _cli([f"resume={ddp}", "trainer.max_epochs=2"], tmp / "runs", datasets, work)
    return {"ddp": ddp, "single": single, "ddp_out": ddp_out, "single_out": single_out, "before": before,
            "weights_before": weights_before, "resumed": resumed, "root": tmp}


def test_the_run_was_data_parallel(runs):
    text = runs["ddp_out"].stdout + runs["ddp_out"].stderr
    assert "distributed_backend=gloo" in text and "Starting with 2 processes" in text, text[-2000:]


def test_each_rank_draws_a_disjoint_part_of_the_single_process_batch(runs):
    ddp = [_draws(runs["ddp"], rank) for rank in (0, 1)]
    single = [d for d in _draws(runs["single"], 0) if d["epoch"] == 0]
    first = [[d for d in ddp[rank] if d["epoch"] == 0] for rank in (0, 1)]
    steps = min(len(first[0]), len(first[1]), len(single))
    assert steps >= 4, f"too few recorded steps: {steps}"
    assert len(first[0]) == len(first[1]), "the ranks drew different numbers of batches (DDP would wait forever)"
    seen: set[int] = set()
    for step in range(steps):
        a, b = first[0][step]["indices"], first[1][step]["indices"]
        assert len(a) == len(b) == PER_RANK and not set(a) & set(b), f"step {step}: the ranks' parts overlap"
        assert a + b == single[step]["indices"], f"step {step}: the ranks' parts are not the single process's batch"
        assert not seen & set(a + b), f"step {step}: samples drawn again within the epoch"
        seen |= set(a + b)


def test_the_loss_is_the_single_process_loss_on_the_same_global_batch(runs):
    ddp, single = dict(_metric_rows(runs["ddp"], "train/loss")), dict(_metric_rows(runs["single"], "train/loss"))
    steps = sorted(set(ddp) & set(single))
    assert len(steps) >= 4, (ddp, single)
    for step in steps:
        assert ddp[step] == pytest.approx(single[step], rel=1e-4), f"step {step}: DDP {ddp[step]} vs one process {single[step]}"
    w_ddp, w_single = runs["weights_before"], _weights(runs["single"])
    assert w_ddp.keys() == w_single.keys()
    # AdamW divides each gradient by its own running scale, so the float rounding of averaging over ranks
    # moves a weight whose gradient is near zero by up to a step; the weights as a whole agree
    diff = torch.cat([(w_ddp[k] - w_single[k]).flatten() for k in w_ddp]).norm()
    norm = torch.cat([w_single[k].flatten() for k in w_single]).norm()
    assert diff / norm < 1e-4, f"the weights after the same steps differ by {diff / norm:.2e} of their norm"


def test_rank_zero_writes_the_run_once(runs):
    root, ddp = runs["root"], runs["ddp"]
    assert sorted(p.name for p in (root / "runs").iterdir()) == ["quickstart", "robot_sdf_panda_quick", "single"]
    assert len(list((root / "runs" / "quickstart").iterdir())) == 1, "the DDP ranks made more than one run folder"
    assert runs["before"]["status"] == "completed" and runs["before"]["steps"] >= 4
    rows = _metric_rows(ddp, "train/loss")
    assert len(rows) == len({s for s, _ in rows}), "a step's training loss was logged twice"
    evaluations = [row for row in _metric_rows(ddp, "eval/success_rate")]
    assert len(evaluations) == 2, f"the in-training evaluation ran {len(evaluations)} times over the two epochs"
    assert (ddp / "checkpoints" / "best.ckpt").is_file() and (ddp / "eval" / "metrics.json").is_file()


def test_resume_of_a_ddp_run_goes_on_in_its_folder(runs):
    ddp = runs["ddp"]
    after = json.loads((ddp / "run.json").read_text())
    assert after["status"] == "completed" and len(after["starts"]) == 2, after.get("starts")
    assert after["epochs"] == runs["before"]["epochs"] + 1 and after["steps"] > runs["before"]["steps"]
    for rank in (0, 1):
        assert {d["epoch"] for d in _draws(ddp, rank)} == {0, 1}, f"rank {rank} drew no batch in the resumed epoch"
    assert "resuming from last.ckpt" in runs["resumed"].stdout


# The robot SDF: a few dozen steps of the tiny settings on two ranks
SDF = ["experiment=robot_sdf_panda", "robot_sdf_samples=tiny", "robot_sdf_eval=tiny", "datamodule.steps_per_epoch=10",
       "datamodule.near_per_step=64", "datamodule.uniform_per_step=32", "trainer.max_steps=20",
       "trainer.enable_progress_bar=false", "trainer.log_every_n_steps=5", "robot_sdf_eval.timing_batches=[1]",
       "model.encoding.levels=4", "model.encoding.log2_table_size=12", "model.encoding.finest=64",
       "datamodule.record_draws=true", *DDP]


def test_robot_sdf_ranks_draw_their_own_samples_and_resume(tmp_path, _isolated_cache):
    (tmp_path / "work").mkdir()
    _cli(SDF, tmp_path / "runs", tmp_path / "datasets", tmp_path / "work")
    (run,) = (tmp_path / "runs" / "robot_sdf_panda").iterdir()
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "completed" and record["steps"] == 20 and (run / "robot_sdf.pt").is_file()
    drawn = [{d["sha256"] for d in _draws(run, rank)} for rank in (0, 1)]
    assert len(drawn[0]) >= 10 and len(drawn[1]) >= 10 and not drawn[0] & drawn[1], "the ranks drew the same batches"
    _cli([f"resume={run}", "trainer.max_steps=30"], tmp_path / "runs", tmp_path / "datasets", tmp_path / "work")
    after = json.loads((run / "run.json").read_text())
    assert after["status"] == "completed" and after["steps"] == 30 and len(after["starts"]) == 2
    assert [p.name for p in (tmp_path / "runs" / "robot_sdf_panda").iterdir()] == [run.name]
