"""`python -m samp.train +experiment=mpinet|mpnet|simpnet` end to end on tiny data: the loss falls, the run is
evaluated into eval/metrics.json like a SAMP run, and `load_planner(run)` gives the baseline back; and the
expert rows of Table I (`planner=expert_raw|ompl_sampling`) through `python -m samp.eval`."""

from __future__ import annotations

import csv
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

COMMON = ["datamodule.n_e=16", "trainer.max_steps=50", "trainer.max_epochs=-1", "trainer.log_every_n_steps=2",
          "trainer.enable_progress_bar=false", "datamodule.batch_size=16", "datamodule.noise=0",
          "datamodule.val_samples=32", "evaluation.problems=1", "evaluation.benchmark=null",
          "system.optimizer.lr=1e-3"]
SMALL = {"mpinet": ["model.robot_points=48", "model.obstacle_points=64", "model.target_points=16",
                    "model.levels=[{centres:32,radius:0.15,neighbours:8,widths:[16,32]}]", "model.global_widths=[32,64]",
                    "model.config_hidden=[16]", "model.decoder_hidden=[64]"],
         "mpnet": ["model.channels=[4,8]", "model.code=16", "model.hidden=[64,32]", "model.dropout=0.1",
                   "system.planning.time_limit=3.0"],
         "simpnet": ["model.channels=[4,8]", "model.cells=2", "model.width=16", "model.heads=2", "model.rounds=1",
                     "model.dropout=0.1", "system.planning.time_limit=3.0", "system.planning.rollout_steps=10"]}


def _train(tmp: Path, root: Path, kind: str) -> Path:
    env = {**os.environ, "SAMP_RUNS_DIR": str(tmp / "runs"), "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1"}
    args = [f"+experiment={kind}", "datamodule.dataset=bl_tiny", f"datamodule.root={root}", *COMMON, *SMALL[kind]]
    proc = subprocess.run([sys.executable, "-m", "samp.train", *args], capture_output=True, text=True, timeout=300, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    runs = list((tmp / "runs" / kind).iterdir())
    assert len(runs) == 1
    return runs[0]


@pytest.mark.parametrize("kind", ["mpinet", "mpnet", "simpnet"])
def test_training_run_improves_its_loss_and_is_evaluated(kind, tiny, tmp_path):
    from samp.eval import StepPolicy, TrajectoryPlanner, load_planner

    run = _train(tmp_path, tiny[1], kind)
    rows = list(csv.DictReader(open(run / "metrics.csv")))
    losses = [float(r["train/loss"]) for r in rows if r.get("train/loss")]
    assert len(losses) >= 10, losses
    first, last = np.mean(losses[:3]), np.mean(losses[-3:])
    assert last < 0.5 * first, f"{kind}: train/loss did not fall: {losses}"
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "completed" and record["dataset_id"].startswith("bl_tiny@")
    report = json.loads((run / "eval" / "metrics.json").read_text())
    assert report["planner"] == kind and report["protocol"] == 2
    assert set(report["metrics"]) == {"train", "val", "train_hard", "val_hard"}, sorted(report["metrics"])
    assert report["expert"]["val"]["success_rate"] == 1.0 and report["straight"]["val"]["problems"] == 1
    assert f"eval/{kind}/val/success_rate" in record["metrics"] and f"eval/{kind}/val/success_rate_ci_low" in record["metrics"]
    planner = load_planner(run)
    assert planner.name == kind
    assert isinstance(planner, StepPolicy if kind == "mpinet" else TrajectoryPlanner)


@pytest.mark.parametrize("planner", ["expert_raw", "ompl_sampling"])
def test_eval_cli_plans_the_expert_rows_afresh(planner, tiny, tmp_path):
    from samp.eval.__main__ import main

    out = tmp_path / planner
    assert main([f"planner={planner}", f"dataset={tiny[0]}", f"out={out}", "splits=[val]", "problems=2",
                 "record=false", "benchmark=null"]) == 0
    report = json.loads((out / "metrics.json").read_text())
    assert report["planner"] == planner and report["metrics"]["val"]["success_rate"] == 1.0
    assert report["expert"]["val"]["success_rate"] == 1.0, "the stored expert is evaluated beside it"
    records = [json.loads(line) for line in (out / "problems.jsonl").read_text().splitlines()]
    mine = [r for r in records if r["planner"] == planner]
    assert len(mine) == 2 and all(r["termination"] == "planned" and r["solution_time"] > 0 for r in mine)


def test_expert_variants_switch_off_post_processing():
    from samp.eval.config import PLANNERS
    from samp.eval.planners import EXPERT_VARIANTS
    from samp.expert import load_expert_config

    assert set(EXPERT_VARIANTS) <= set(PLANNERS)
    raw = load_expert_config(None, **EXPERT_VARIANTS["expert_raw"])
    sampling = load_expert_config(None, **EXPERT_VARIANTS["ompl_sampling"])
    assert not (raw.simplify or raw.smooth) and raw.direct
    assert not (sampling.simplify or sampling.smooth or sampling.direct) and sampling.planner == "RRTConnect"


@pytest.mark.parametrize("kind", ["mpinet", "mpnet", "simpnet"])
def test_default_experiments_compose_and_instantiate(kind):
    from hydra.utils import instantiate

    from samp.train import compose_train_config

    cfg = compose_train_config([f"+experiment={kind}"])
    assert cfg.name == kind and cfg.datamodule.n_e == 100 and cfg.trainer.max_epochs == 160, "samp_n100's data and budget"
    system = instantiate(cfg.system)
    assert system.kind == kind and system.net_cfg.dof == 7
    with pytest.raises(ValueError, match="unknown key"):
        compose_train_config([f"+experiment={kind}", "+system.robot_sdf=robot_sdf_panda"])


def test_mpinet_paper_sizes_are_a_named_configuration():
    from hydra.utils import instantiate

    from samp.train import compose_train_config

    cfg = compose_train_config(["+experiment=mpinet", "model=mpinet_paper"])
    system = instantiate(cfg.system)
    c = system.net_cfg
    assert (c.robot_points, c.obstacle_points, c.target_points) == (2048, 4096, 128) and not c.goal_config
    assert [(lv.centres, lv.radius, lv.neighbours) for lv in c.levels] == [(512, 0.05, 128), (128, 0.3, 128)]
    assert system.robot_surface.points.shape == (2048, 3) and system.target_surface.points.shape == (128, 3)
