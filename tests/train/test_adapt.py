"""`python -m samp.train.adapt` (samp/train/adapt.py) and `init_from=` (samp/train/init_from.py).

Fast: the one-line refusals (a missing folder, a folder without scene files, a from-run that is not a
trained policy run) and `load_initial_weights` on a hand-made run (weights copied exactly, another network
refused). Slow: the command end to end, shrunk, on a tiny policy trained here and two cuRobo-style worlds
written here."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

REPO = Path(__file__).resolve().parents[2]

WORLDS = {
    "box": """cuboid:
  floor: {dims: [2.0, 2.0, 0.1], pose: [0.0, 0.0, -0.05, 1.0, 0.0, 0.0, 0.0]}
  box: {dims: [0.2, 0.2, 0.2], pose: [0.55, 0.3, 0.1, 1.0, 0.0, 0.0, 0.0]}
""",
    "post": """cuboid:
  floor: {dims: [2.0, 2.0, 0.1], pose: [0.0, 0.0, -0.05, 1.0, 0.0, 0.0, 0.0]}
cylinder:
  post: {radius: 0.04, height: 0.6, pose: [0.5, -0.35, 0.3, 1.0, 0.0, 0.0, 0.0]}
""",
}


def _write_worlds(folder: Path) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in WORLDS.items():
        (folder / f"{name}.yaml").write_text(text)
    return folder


def _fake_run(path: Path, net: torch.nn.Module, *, status: str = "completed", policy: bool = True) -> Path:
    """A run folder as samp.train leaves one: run.json and checkpoints/last.ckpt holding `net`'s weights."""
    (path / "checkpoints").mkdir(parents=True)
    config = {"model": {"_target_": "x.Net"}, "datamodule": {"dataset": "smoke", "n_e": 16}} if policy else \
        {"model": {"_target_": "x.Sdf"}, "datamodule": {"_target_": "x.Samples"}}
    (path / "run.json").write_text(json.dumps({"status": status, "experiment": "x", "config": config}))
    torch.save({"state_dict": net.state_dict(), "samp": {"kind": "samp"}}, path / "checkpoints" / "last.ckpt")
    return path


def _adapt(argv: list[str], capsys) -> tuple[int, str]:
    from samp.train.adapt import main

    rc = main(argv)
    return rc, capsys.readouterr().err


def test_a_missing_folder_is_refused_in_one_line(tmp_path, capsys):
    run = _fake_run(tmp_path / "run", torch.nn.Linear(3, 2))
    rc, err = _adapt([f"from={run}", f"cells={tmp_path / 'nowhere'}"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "no such folder" in err, err


def test_a_folder_without_scene_files_is_refused(tmp_path, capsys):
    run = _fake_run(tmp_path / "run", torch.nn.Linear(3, 2))
    (tmp_path / "cells").mkdir()
    (tmp_path / "cells" / "notes.txt").write_text("no scenes here")
    rc, err = _adapt([f"from={run}", f"cells={tmp_path / 'cells'}"], capsys)
    assert rc == 2 and err.count("\n") == 1 and "holds no scene files" in err, err


@pytest.mark.parametrize("kind", ["empty", "robot_sdf", "failed"])
def test_a_from_run_that_is_not_a_trained_policy_is_refused(tmp_path, capsys, kind):
    cells = _write_worlds(tmp_path / "cells")
    run = tmp_path / "run"
    if kind == "empty":
        run.mkdir()
    else:
        _fake_run(run, torch.nn.Linear(3, 2), status="failed" if kind == "failed" else "completed",
                  policy=kind != "robot_sdf")
    rc, err = _adapt([f"from={run}", f"cells={cells}"], capsys)
    expected = {"empty": "is not a run folder", "robot_sdf": "is not a policy run", "failed": "not a trained policy run"}
    assert rc == 2 and err.count("\n") == 1 and expected[kind] in err, err


def test_missing_arguments_are_named(capsys):
    rc, err = _adapt(["cells=somewhere"], capsys)
    assert rc == 2 and "from=..." in err, err


def test_initial_weights_are_the_from_runs_and_another_network_is_refused(tmp_path):
    from samp.train.init_from import load_initial_weights, weights_hash

    torch.manual_seed(0)
    source = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    run = _fake_run(tmp_path / "run", source)
    target = torch.nn.Sequential(torch.nn.Linear(3, 4), torch.nn.Linear(4, 2))
    lineage = load_initial_weights(target, run)
    for name, value in source.state_dict().items():
        torch.testing.assert_close(target.state_dict()[name], value, rtol=0, atol=0, msg=name)
    assert lineage["run"] == str(run) and lineage["checkpoint"].endswith("last.ckpt")
    assert lineage["weights_sha256"] == weights_hash(source.state_dict())
    other = torch.nn.Sequential(torch.nn.Linear(3, 5), torch.nn.Linear(5, 2))
    with pytest.raises(ValueError, match=r"does not fit this run.s \(3 shape\(s\) differ.*0.bias is \(4,\) there, \(5,\) here"):
        load_initial_weights(other, run)


def test_dagger_names_file_scenes_by_their_files_in_scene_order():
    """A dataset's file scenes follow its generated ones, split by split, as the spec's expansion lists them."""
    from types import SimpleNamespace

    from samp.train.dagger import scene_refs

    scenes = [{"generator": "tabletop", "seed": 7}, {"generator": "file", "seed": 1}, {"generator": "file", "seed": 2},
              {"generator": "file", "seed": 3}]
    config = {"scene_files": {"train": ["cells"], "test": ["other.yaml"]},
              "scene_file_expansion": {"train": ["cells/a.yaml", "cells/b.yaml"], "test": ["other.yaml"]}}
    ds = SimpleNamespace(name="mine", id="abc", manifest={"scenes": scenes, "config": config})
    assert scene_refs(ds) == ["tabletop:7", "cells/a.yaml", "cells/b.yaml", "other.yaml"]
    ds.manifest["scenes"] = scenes[:2]  # fewer file scenes than files: the manifest does not add up
    with pytest.raises(ValueError, match="scene files do not match"):
        scene_refs(ds)


# ------------------------------------------------------------------------------------------- end to end
TINY_SDF = "build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']"


def _run(cmd: list[str], env: dict, cwd: Path) -> str:
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=env, cwd=cwd)
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-3000:]
    return out.stdout


@pytest.mark.slow
def test_adapt_end_to_end_shrunk(tmp_path, _isolated_cache):
    """A tiny policy (the smoke dataset, n_e 16, one epoch of four batches), adapted to two worlds with a few
    demonstrations, one DAgger round and one short epoch: the adapted run starts from the from-run's weights
    and names it, before and after are evaluated on the same problems, none of them a demonstration."""
    from samp.data import open_dataset
    from samp.train.init_from import weights_hash

    env = {k: v for k, v in os.environ.items() if k != "SAMP_TRACKING_URI"}
    env.update(PYTHONPATH=str(REPO), SAMP_RUNS_DIR=str(tmp_path / "runs"), SAMP_DATASETS_DIR=str(tmp_path / "datasets"),
               SAMP_TRACKING_URI="off", OMP_NUM_THREADS="1")
    (tmp_path / "work").mkdir()
    _run([sys.executable, "-m", "samp.train", "+experiment=quickstart", "datamodule.dataset=smoke", "datamodule.n_e=16",
          "datamodule.val_samples=50", "trainer.max_epochs=1", "+trainer.limit_train_batches=4",
          "evaluation.problems=1", "evaluation.benchmark=null", TINY_SDF], env, tmp_path / "work")
    (before,) = (tmp_path / "runs" / "quickstart").iterdir()
    cells = _write_worlds(tmp_path / "my_cells")
    out = _run([sys.executable, "-m", "samp.train.adapt", f"from={before}", f"cells={cells}", "trajectories=4",
                "eval_problems=3", "epochs=1", "workers=1", "+trainer.limit_train_batches=2", "dagger.per_scene=2",
                "datamodule.val_samples=20"], env, tmp_path / "work")
    (after,) = (tmp_path / "runs" / "adapt_my_cells").iterdir()
    record = json.loads((after / "run.json").read_text())
    assert record["status"] == "completed" and record["adapt_from"] == str(before)
    assert record["init_from"]["run"] == str(before)
    ckpt = torch.load(record["init_from"]["checkpoint"], map_location="cpu", weights_only=False)
    assert record["init_from"]["weights_sha256"] == weights_hash(ckpt["state_dict"]), "the first weights differ"
    assert record["config"]["dagger"]["teacher"] == str(before)

    report = json.loads((after / "adapt.json").read_text())
    starts = {label: [(r["problem"], tuple(r["q_start"])) for r in report["records"][label]] for label in ("before", "after")}
    assert starts["before"] == starts["after"] and len(starts["before"]) == len(report["problems"]) == 2 * 3
    assert report["metrics"]["before"]["cells"]["problems"] == report["metrics"]["after"]["cells"]["problems"] == 6
    trained = open_dataset(record["dataset_id"].split("@")[0], tmp_path / "datasets")  # the aggregated dataset
    assert trained.name.startswith("adapt_my_cells_dagger_")
    demos = {(tuple(np.round(t[0].numpy(), 6)), tuple(np.round(t[-1].numpy(), 6))) for t in trained.trajectories}
    asked = {(tuple(np.round(p["q_start"], 6)), tuple(np.round(p["q_goal"], 6))) for p in report["problems"]}
    assert asked and not asked & demos, "an evaluation problem is a training demonstration"
    table = (after / "adapt.md").read_text()
    assert "| before | cells" in table and "| after | cells" in table
    assert "| before | cells" in out and "adapt 4/4" in out and (after / "adapt_spec.yaml").is_file()
