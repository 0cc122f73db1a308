"""The DAgger stage of the training recipe (`dagger.rounds=1`, samp/train/dagger.py), run for real through
the CLI on a tiny dataset: a teacher trained as a run of its own, rolled out in the training scenes, the
expert's plans from the states it visited imported beside the dataset's own demonstrations, and the run
trained and evaluated on that aggregated dataset. The plans are checked against the independent pybullet
check and against the problems they came from; the same command again finds the teacher and the dataset
instead of making them anew."""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow

# two training scenes of three demonstrations; the teacher trains on the first only (max_scenes=1), and is rolled
# out there alone; a teacher of four batches mostly collides
SPEC = {"name": "dg_tiny", "robot": "panda", "seed": 7, "train_scenes": 2, "val_scenes": 1,
        "trajectories_per_scene": 3, "eval_problems_per_scene": 3, "generators": ["tabletop"], "resolutions": [16]}
ARGS = ["experiment=quickstart", "datamodule.dataset=dg_tiny", "datamodule.n_e=16", "datamodule.val_samples=20",
        "trainer.max_epochs=1", "+trainer.limit_train_batches=4", "trainer.enable_progress_bar=false",
        "evaluation.problems=1", "evaluation.benchmark=null", "dagger.rounds=1", "dagger.per_scene=3",
        "dagger.clean_share=1", "datamodule.max_scenes=1",
        "build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']"]


@pytest.fixture(scope="module")
def staged(tmp_path_factory, _isolated_cache):
    from samp.data import generate

    tmp = tmp_path_factory.mktemp("dagger")
    runs, datasets, work = tmp / "runs", tmp / "datasets", tmp / "work"
    work.mkdir()
    base = generate(SPEC, root=datasets, progress=False)
    env = {**os.environ, "SAMP_RUNS_DIR": str(runs), "SAMP_DATASETS_DIR": str(datasets), "RERUN_ANALYTICS": "0",
           "SAMP_TRACKING_URI": "off"}
    out = subprocess.run([sys.executable, "-m", "samp.train", *ARGS], capture_output=True, text=True, env=env,
                         cwd=work, timeout=900)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    (teacher,) = (runs / "quickstart_round0").iterdir()
    (run,) = (runs / "quickstart").iterdir()
    return {"runs": runs, "datasets": datasets, "base": base, "teacher": teacher, "run": run, "stdout": out.stdout}


def test_the_run_trains_on_the_aggregated_dataset_its_teacher_made(staged):
    from samp.data.registry import verify_dataset

    teacher = json.loads((staged["teacher"] / "run.json").read_text())
    record = json.loads((staged["run"] / "run.json").read_text())
    assert teacher["status"] == record["status"] == "completed"
    assert teacher["dataset_id"] == f"dg_tiny@{staged['base'].name}" and teacher["dagger_key"]
    assert not (staged["teacher"] / "eval").exists(), "the teacher is not evaluated: only the run is"
    assert teacher["config"]["datamodule"]["max_scenes"] == 1 and "problems of 1 training scene" in staged["stdout"]
    name, _, ident = record["dataset_id"].partition("@")
    assert name.startswith("dg_tiny_dagger_") and record["config"]["datamodule"]["dataset"] == record["dataset_id"]
    assert record["config"]["dagger"]["teacher"] == str(staged["teacher"])
    assert verify_dataset(staged["datasets"] / name / ident) == []
    assert json.loads((staged["run"] / "eval" / "metrics.json").read_text())["dataset"] == record["dataset_id"]


def test_the_added_demonstrations_start_where_the_teacher_went_and_are_collision_free(staged):
    """The aggregated dataset holds the base dataset's demonstrations unchanged, and the expert plans the
    round printed (at most one per rollout; this teacher collides on most): each from a state that is no
    stored start, to the goal of a training demonstration, in the scene the teacher trained on,
    collision-free by pybullet. Collecting again from the same teacher and seed gives the same plans."""
    import torch

    from samp.data import open_dataset
    from samp.eval.checks import TrajectoryChecker
    from samp.policy.registry import load_system
    from samp.robot import load_robot
    from samp.train.dagger import collect

    record = json.loads((staged["run"] / "run.json").read_text())
    base, agg = open_dataset(staged["base"]), open_dataset(record["dataset_id"], staged["datasets"])
    own = [t.numpy() for t in base.trajectories]
    got = [t.numpy() for t in agg.trajectories]
    (planned,) = map(int, re.findall(r"(\d+) expert plans from visited states", staged["stdout"]))
    assert planned >= 1 and len(got) == len(own) + planned
    key = lambda t: t.round(9).tobytes()  # noqa: E731 - the import may reorder trajectories
    own_keys = {key(t) for t in own}
    assert own_keys <= {key(t) for t in got}
    starts = {tuple(t[0].round(9)) for t in own}
    train = base.scene_indices("train")
    goals = {tuple(own[k][-1].round(9)) for k in np.flatnonzero(np.isin(base.traj_scene.numpy(), train))}
    new = [(t, s) for t, s in zip(got, agg.traj_scene.tolist()) if key(t) not in own_keys]
    assert len(new) == planned
    teacher = load_system(staged["teacher"])
    again = [collect(teacher, base, 3, 3, 1.0, seed=0, scenes=train[:1], progress=False) for _ in range(2)]
    assert [key(t) for t in again[0][0]] == [key(t) for t in again[1][0]]
    assert len(again[0][0]) == len(new)  # what the round imported, which the import resamples: same ends
    ends = lambda t: np.concatenate([t[0], t[-1]])  # noqa: E731
    assert all(any(np.allclose(ends(t), ends(q), atol=1e-6) for t, _ in new) for q in again[0][0])
    with TrajectoryChecker(load_robot("panda", dtype=torch.float64)) as checker:
        for t, s in new:
            assert agg.manifest["scenes"][s]["split"] == "train"
            assert tuple(t[-1].round(9)) in goals and tuple(t[0].round(9)) not in starts
            assert agg.scene_hashes[s] == base.scene_hashes[train[0]]
            assert not checker.check(agg.scenes[s], [t])[0]["collision"]


def test_the_same_command_again_finds_the_teacher_and_the_dataset_and_a_teacher_may_be_given(staged, monkeypatch,
                                                                                              capsys):
    from omegaconf import open_dict

    from samp.train.config import compose_train_config
    from samp.train.prerequisites import prepare

    record = json.loads((staged["run"] / "run.json").read_text())
    monkeypatch.setenv("SAMP_TRACKING_URI", "off")
    cfg = compose_train_config(record["overrides"])
    with open_dict(cfg):
        cfg.paths.runs_dir, cfg.paths.datasets_dir = str(staged["runs"]), str(staged["datasets"])
        prepare(cfg, record["overrides"])
    assert cfg.datamodule.dataset == record["dataset_id"]
    assert len(list((staged["runs"] / "quickstart_round0").iterdir())) == 1
    assert len(list((staged["datasets"] / record["dataset_id"].split("@")[0]).iterdir())) == 1
    out = capsys.readouterr().out
    assert "was trained before with the same config: using it" in out and "was aggregated from" in out
    # a teacher given by its folder (any trained run) is rolled out in place of one the stage trains
    given = [*record["overrides"], f"dagger.teacher={staged['teacher']}"]
    cfg = compose_train_config(given)
    with open_dict(cfg):
        cfg.paths.runs_dir, cfg.paths.datasets_dir = str(staged["runs"]), str(staged["datasets"])
        prepare(cfg, given)
    assert cfg.datamodule.dataset == record["dataset_id"] and "rolls out the given teacher" in capsys.readouterr().out


def test_settings_and_datasets_it_cannot_use_are_refused_before_a_teacher_is_trained(staged, tmp_path):
    from types import SimpleNamespace

    from omegaconf import OmegaConf

    from samp.train.dagger import scene_refs, stage

    base = json.loads((staged["teacher"] / "run.json").read_text())["dataset_id"]
    cfg = OmegaConf.create({"name": "x", "seed": 0, "datamodule": {"dataset": base},
                            "paths": {"runs_dir": str(tmp_path), "datasets_dir": str(staged["datasets"])},
                            "system": {}, "dagger": {"rounds": 1, "teacher": None, "per_scene": 0, "back": 3,
                                                     "clean_share": 0.1}})
    with pytest.raises(ValueError, match="dagger.per_scene must be >= 1"):
        stage(cfg, [])
    cfg.dagger.per_scene, cfg.dagger.scenes = 3, "mine"
    with pytest.raises(ValueError, match="dagger.scenes must be teacher or run, got 'mine'"):
        stage(cfg, [])
    cfg.dagger.scenes, cfg.datamodule.max_trajectories = "teacher", 10
    with pytest.raises(ValueError, match="cannot be combined with datamodule.max_trajectories"):
        stage(cfg, [])
    assert not any(tmp_path.iterdir())
    files = SimpleNamespace(name="mine", id="abc", manifest={"scenes": [{"generator": "file", "seed": None}],
                                                              "config": {}})
    with pytest.raises(ValueError, match="mine@abc: its manifest's scene files do not match its file scenes"):
        scene_refs(files)
    imported = SimpleNamespace(name="mine", id="abc", manifest={"scenes": [{"generator": "import", "seed": 0}],
                                                                 "config": {}})
    with pytest.raises(ValueError, match="mine@abc has imported scenes.*dagger.rounds=0"):
        scene_refs(imported)
