"""The recipe's prerequisites (samp.train.prerequisites): a dataset whose spec changed is generated anew,
a dataset the evaluation after training cannot use is refused before training, and robot SDF names
resolve to their newest completed run."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from samp.data import generate, open_dataset, write_dataset

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SPEC = {"name": "prereq", "robot": "panda", "seed": 2, "train_scenes": 1, "val_scenes": 0, "test_scenes": 0,
        "trajectories_per_scene": 1, "eval_problems_per_scene": 1, "generators": ["tabletop"], "resolutions": [8]}


def _cfg(root, dataset: str, build: bool = True, problems: int = 1):
    return OmegaConf.create({"datamodule": {"dataset": dataset, "root": str(root)}, "paths": {"datasets_dir": str(root)},
                             "build_missing": {"dataset": build, "workers": 1}, "evaluation": {"problems": problems},
                             "system": {}})


@pytest.fixture(scope="module")
def built(tmp_path_factory, _isolated_cache):
    root = tmp_path_factory.mktemp("prereq")
    return root, open_dataset(generate(SPEC, root=root, progress=False))


def test_a_dataset_without_evaluation_problems_is_refused_before_training(built, tmp_path):
    from samp.train.prerequisites import prepare

    import copy

    old = copy.copy(built[1])
    old.eval_problems, old.has_eval_problems = [], False  # as a dataset written before they existed
    write_dataset(old, name="old", root=tmp_path)
    with pytest.raises(ValueError, match="old@.* stores no evaluation problems.*evaluation.problems=0"):
        prepare(_cfg(tmp_path, "old", build=False))
    prepare(_cfg(tmp_path, "old", build=False, problems=0))  # not evaluated after training: fine


def test_a_spec_changed_since_its_dataset_is_generated_anew(built, monkeypatch, tmp_path):
    """With the spec in a conf folder of its own (SAMP_CONF_DIR), edited after its dataset was built."""
    import shutil

    import yaml

    from samp.paths import conf_dir
    from samp.train.prerequisites import prepare

    root, ds = built
    conf = tmp_path / "conf"
    shutil.copytree(conf_dir(), conf)
    (conf / "dataset" / "prereq.yaml").write_text(yaml.safe_dump(SPEC))
    monkeypatch.setenv("SAMP_CONF_DIR", str(conf))
    prepare(_cfg(root, "prereq"))
    assert open_dataset("prereq", root).id == ds.id, "the same spec: its dataset is used as it is"
    (conf / "dataset" / "prereq.yaml").write_text(yaml.safe_dump({**SPEC, "eval_problems_per_scene": 2}))
    prepare(_cfg(root, "prereq"))
    newest = open_dataset("prereq", root)
    assert newest.id != ds.id and len(newest.eval_problems) == 2, "the current spec's dataset was generated"
    prepare(_cfg(root, "prereq"))  # and is the one found next time: nothing more is generated
    assert sorted(p.name for p in (root / "prereq").iterdir() if not p.name.startswith(".")) == sorted([ds.id, newest.id])


def test_a_robot_sdf_name_resolves_to_its_newest_completed_run(tmp_path):
    from samp.runs import RunFolder
    from samp.train.prerequisites import resolve_robot_sdf

    older = RunFolder.create_at(tmp_path / "robot_sdf_panda" / "2026-01-01_00-00-00")
    newer = RunFolder.create_at(tmp_path / "robot_sdf_panda" / "2026-02-01_00-00-00")
    for run in (older, newer):
        (run.path / "robot_sdf.pt").write_bytes(b"x")
    older.update(status="completed")
    newer.update(status="failed")  # the newest is not completed: the older one is used
    assert resolve_robot_sdf("robot_sdf_panda", tmp_path) == older.path
    with pytest.raises(FileNotFoundError, match="experiment=robot_sdf_iiwa"):
        resolve_robot_sdf("robot_sdf_iiwa", tmp_path)


def _sdf_run(root, name: str, stamp: str, target: str, content: bytes):
    from samp.robot_sdf.artifact import artifact_id
    from samp.runs import RunFolder

    run = RunFolder.create_at(root / name / stamp)
    (run.path / "robot_sdf.pt").write_bytes(content)
    run.update(status="completed", config={"model": {"_target_": target}},
               robot_sdf_artifact_id=artifact_id(run.path / "robot_sdf.pt"))
    return run.path


HASH, NN = "samp.robot_sdf.model.UnifiedHashSDF", "samp.robot_sdf.baselines.NNSDF"


def test_a_robot_sdf_name_resolves_only_among_runs_of_the_network_its_experiment_trains(tmp_path):
    """An NN-SDF run made later under the same experiment name (the README's baseline command) is not what
    `robot_sdf_panda` means; `NAME@ID` picks any run by its artifact's content id."""
    from samp.robot_sdf.artifact import artifact_id
    from samp.train.prerequisites import resolve_robot_sdf

    hash_run = _sdf_run(tmp_path, "robot_sdf_panda", "2026-01-01_00-00-00", HASH, b"hash grid")
    nn_run = _sdf_run(tmp_path, "robot_sdf_panda", "2026-02-01_00-00-00", NN, b"nn-sdf")
    assert resolve_robot_sdf("robot_sdf_panda", tmp_path) == hash_run
    nn_id = artifact_id(nn_run / "robot_sdf.pt")
    assert resolve_robot_sdf(f"robot_sdf_panda@{nn_id[:6]}", tmp_path) == nn_run
    with pytest.raises(FileNotFoundError, match=f"id starts with 'zz'.*{nn_id}"):
        resolve_robot_sdf("robot_sdf_panda@zz", tmp_path)
    (hash_run / "run.json").unlink()  # only the NN-SDF run is left: the name finds nothing, and says what is there
    with pytest.raises(FileNotFoundError, match=f"UnifiedHashSDF.*not taken by name.*{nn_id}"):
        resolve_robot_sdf("robot_sdf_panda", tmp_path)


def test_an_ambiguous_robot_sdf_name_lists_the_candidates(tmp_path):
    from samp.runs import RunFolder
    from samp.train.prerequisites import resolve_robot_sdf

    a = _sdf_run(tmp_path, "my_sdfs", "2026-01-01_00-00-00", HASH, b"a")
    b = _sdf_run(tmp_path, "my_sdfs", "2026-02-01_00-00-00", NN, b"b")
    with pytest.raises(ValueError, match="ambiguous") as err:
        resolve_robot_sdf("my_sdfs", tmp_path)  # no conf/experiment/my_sdfs.yaml says which network is meant
    assert str(a) in str(err.value) and str(b) in str(err.value), str(err.value)
    RunFolder(a).update(robot_sdf_artifact_id="abc111111111")
    RunFolder(b).update(robot_sdf_artifact_id="abc222222222")
    with pytest.raises(ValueError, match="ambiguous: 2 artifacts' ids start with 'abc'"):
        resolve_robot_sdf("my_sdfs@abc", tmp_path)
    assert resolve_robot_sdf("my_sdfs@abc2", tmp_path) == b
