"""Dataset specs over folders and globs of world files, and benchmarks of a problem set's own problems.

Oracles: the spec's hash before and after one file's content changes, and the stored evaluation problems
against the starts and goals written into the file (bit for bit)."""

from __future__ import annotations

import numpy as np
import pytest
import yaml

READY = [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785]  # the Panda's ready pose, clear of everything below
GOALS = [[0.4, -0.6, 0.0, -2.2, 0.0, 1.7, 0.785], [-0.5, -0.5, 0.2, -2.0, 0.0, 1.6, 0.5]]
FAR_WALL = {"cuboid": {"wall": {"dims": [0.05, 1.0, 0.8], "pose": [0.95, 0.0, 0.4, 1.0, 0.0, 0.0, 0.0]}}}


def spec(**extra) -> dict:
    return {"name": "worlds", "robot": "panda", "seed": 3, "train_scenes": 0, "val_scenes": 0, "test_scenes": 0,
            "trajectories_per_scene": 0, "eval_problems_per_scene": 2, "resolutions": [8], **extra}


def world(folder, name: str, x: float):
    folder.mkdir(exist_ok=True)
    (folder / f"{name}.yaml").write_text(yaml.safe_dump(
        {"cuboid": {"crate": {"dims": [0.2, 0.2, 0.2], "pose": [x, 0.5, 0.1, 1.0, 0.0, 0.0, 0.0]}}}))


@pytest.mark.parametrize("entry", ["cells", "cells/*.yaml"])
def test_a_folder_or_glob_expands_sorted_and_its_files_contents_set_the_hash(tmp_path, monkeypatch, entry):
    from samp.data.spec import load_spec

    monkeypatch.setenv("SAMP_HOME", str(tmp_path))  # relative references are looked up in the project folder
    for name, x in (("b", 0.6), ("a", 0.5)):
        world(tmp_path / "cells", name, x)
    first = load_spec(spec(scene_files={"test": [entry]}))
    resolved = first.resolved()
    assert resolved["scene_file_expansion"] == {"test": ["cells/a.yaml", "cells/b.yaml"]}
    assert [j.scene_file for j in first.scene_jobs()] == ["cells/a.yaml", "cells/b.yaml"]
    before = first.config_hash()
    world(tmp_path / "cells", "b", 0.7)  # one file's content changes, its name does not
    assert load_spec(spec(scene_files={"test": [entry]})).config_hash() != before
    world(tmp_path / "cells", "c", 0.4)  # a file is added
    grown = load_spec(spec(scene_files={"test": [entry]}))
    assert len(grown.scene_jobs()) == 3 and grown.config_hash() != before


def test_problems_from_files_need_a_file_with_problems(tmp_path):
    from samp.data.spec import load_spec

    world(tmp_path, "plain", 0.5)
    with pytest.raises(ValueError, match="gives no problems of its own"):
        load_spec(spec(scene_files={"test": [str(tmp_path / "plain.yaml")]}, problems_from_files=True))
    with pytest.raises(ValueError, match="scene_files.test is empty"):
        load_spec(spec(test_scenes=1, problems_from_files=True))


def test_a_benchmark_of_a_problem_sets_own_problems(tmp_path):
    """Two problems in one scene and one whose only goal lies outside the joint limits: the dataset's
    evaluation problems are exactly the two valid starts and goals, the third is kept as skipped, with
    its reason, and the expert's solution is stored for each."""
    from samp.data import generate, open_dataset
    from samp.data.spec import load_spec
    from samp.eval.problems import problems_from_dataset

    beyond = [3.2, -0.5, 0.0, -2.0, 0.0, 1.6, 0.785]  # joint 1 beyond the Panda's 2.8973 rad
    problems = [{"start": READY, "goal_ik": [GOALS[0]], "obstacles": FAR_WALL},
                {"start": GOALS[0], "goal_ik": [beyond, GOALS[1]], "obstacles": FAR_WALL},  # the valid one is taken
                {"start": READY, "goal_ik": [beyond], "obstacles": FAR_WALL}]
    (tmp_path / "set.yaml").write_text(yaml.safe_dump({"far_wall": problems}))
    s = load_spec(spec(scene_files={"test": [str(tmp_path / "set.yaml")]}, problems_from_files=True))
    (job,) = s.scene_jobs()
    assert job.scene_file.endswith("set.yaml#far_wall/0") and job.file_problems and job.eval_problems == 3
    ds = open_dataset(generate(s, root=tmp_path / "datasets", progress=False))
    got = problems_from_dataset(ds, "test")
    np.testing.assert_array_equal([p.q_start for p in got], [READY, GOALS[0]])
    np.testing.assert_array_equal([p.q_goal for p in got], [GOALS[0], GOALS[1]])
    assert all(p.expert_trajectory is not None for p in got), [p.expert_reason for p in got]
    skipped = [p for p in ds.eval_problems if p["goal"] is None]
    assert len(skipped) == 1 and skipped[0]["reason"].startswith("no valid goal (joint limits)"), skipped
