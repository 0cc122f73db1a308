"""`python -m samp.eval`: the files it writes, run folders, and clear errors on bad input (exit code 2)."""

from __future__ import annotations

import json
import sys
import types

import pytest

from samp.eval.__main__ import main
from samp.eval.names import METRICS_JSON, METRICS_MD, PROBLEMS_JSONL, RECORDING_RRD

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


def _run_folder(tmp_path, dataset, robot="panda", asset_hash=None, checkpoint=True):
    run = tmp_path / "run"
    (run / "checkpoints").mkdir(parents=True)
    (run / "run.json").write_text(json.dumps({"status": "completed", "dataset": str(dataset),
                                              "robot": {"name": robot, "asset_hash": asset_hash}}))
    if checkpoint:
        (run / "checkpoints" / "last.ckpt").write_bytes(b"not a real checkpoint")
    return run


class _Calls(list):
    """The fake package's load_policy calls; `.module` is the package."""


@pytest.fixture
def fake_policy_package(monkeypatch, panda):
    """A stand-in for samp.policy: its load_policy returns the straight-line baseline (for the robot
    named by `calls.robot`, panda by default)."""
    from samp.eval import StraightLinePolicy

    calls = _Calls()
    module = types.ModuleType("samp.policy")

    def load_policy(checkpoint, run_dir, **options):
        calls.append((checkpoint, run_dir))
        return StraightLinePolicy(getattr(load_policy, "robot", panda))

    module.load_policy = load_policy
    monkeypatch.setitem(sys.modules, "samp.policy", module)
    calls.module = module
    return calls


def _error(capsys) -> str:
    return capsys.readouterr().err


def test_cli_evaluates_the_expert_and_writes_its_files(tiny_eval, tmp_path, capsys):
    folder, _ = tiny_eval
    out = tmp_path / "expert"
    assert main(["planner=expert", f"dataset={folder}", f"out={out}", "record_rollouts=2", "benchmark=null"]) == 0
    printed = capsys.readouterr().out
    rows = {tuple(c.strip() for c in line.strip("|").split("|"))[:3] for line in printed.splitlines() if line.startswith("| ")}
    assert ("expert", "val", "3") in rows and ("expert", "train", "3") in rows, rows
    assert ("straight", "val", "3") in rows, "the straight line is a row of every table"
    assert "The full table" in printed and "| self-coll. [%] |" in (out / METRICS_MD).read_text(), "metrics.md: all columns"
    for name in (METRICS_JSON, METRICS_MD, PROBLEMS_JSONL, RECORDING_RRD):
        assert (out / name).is_file(), f"{name} not written"
    report = json.loads((out / METRICS_JSON).read_text())
    assert report["protocol"] == 2 and report["benchmark"] is None
    for split in ("train", "val"):
        assert report["metrics"][split]["success_rate"] == 1.0 and report["metrics"][split]["collision_rate"] == 0.0
        assert report["groups"][split]["problems"] == 3 and "stored evaluation problems" in report["groups"][split]["source"]
    assert report["expert"] is None, "the expert is not compared with itself"
    records = [json.loads(line) for line in (out / PROBLEMS_JSONL).read_text().splitlines()]
    expert = [r for r in records if r["planner"] == "expert"]
    assert len(expert) == 6 and all(len(r["trajectory"]) == 50 for r in expert)
    assert {r["group"] for r in records} == {"train", "val"} and len(records) == 12


def test_cli_evaluates_a_run_and_the_expert_beside_it(tiny_eval, tmp_path, capsys, fake_policy_package, panda):
    folder, _ = tiny_eval
    run = _run_folder(tmp_path, folder, asset_hash=panda.asset_hash)
    assert main([f"run={run}", "split=heldout", "problems=2", "record=false", "benchmark=null"]) == 0, _error(capsys)
    assert fake_policy_package == [(run / "checkpoints" / "last.ckpt", run)]
    report = json.loads((run / "eval" / METRICS_JSON).read_text())
    assert report["planner"] == "straight" and report["groups"]["val"]["problems"] == 2 and "train" not in report["groups"]
    assert report["expert"]["val"]["success_rate"] == 1.0
    assert report["metrics"]["val"]["reach_rate"] == 1.0, "the straight line reaches every goal"
    records = [json.loads(line) for line in (run / "eval" / PROBLEMS_JSONL).read_text().splitlines()]
    assert sorted(r["planner"] for r in records) == ["expert", "expert", "straight", "straight"]
    assert not (run / "eval" / RECORDING_RRD).exists()


def test_evaluating_a_run_again_writes_beside_the_earlier_evaluation(tiny_eval, tmp_path, capsys, fake_policy_package,
                                                                     panda):
    """As after training (which writes eval/): the next evaluation goes to eval-2/, then eval-3/, leaving the
    earlier files as they were; overwrite=true replaces eval/; a given out= holding one is refused."""
    run = _run_folder(tmp_path, tiny_eval[0], asset_hash=panda.asset_hash)
    args = [f"run={run}", "splits=[val]", "problems=2", "record=false", "benchmark=null"]
    assert main(args) == 0, _error(capsys)
    first = (run / "eval" / METRICS_JSON).read_bytes()
    assert main([*args, "problems=1"]) == 0, _error(capsys)
    assert f"this one goes to {run / 'eval-2'}" in capsys.readouterr().out
    assert (run / "eval" / METRICS_JSON).read_bytes() == first, "the earlier evaluation was changed"
    assert json.loads((run / "eval-2" / METRICS_JSON).read_text())["groups"]["val"]["problems"] == 1
    assert main(args) == 0 and (run / "eval-3" / METRICS_JSON).is_file()
    assert main([*args, "problems=1", "overwrite=true"]) == 0, _error(capsys)
    assert json.loads((run / "eval" / METRICS_JSON).read_text())["groups"]["val"]["problems"] == 1
    assert not (run / "eval-4").exists()
    assert main([*args, f"out={run / 'eval'}"]) == 2
    assert "overwrite=true" in _error(capsys), "a folder the user names is not replaced silently"


def test_without_a_run_the_evaluation_goes_under_the_configured_runs_folder(tiny_eval, tmp_path, capsys, monkeypatch):
    from samp.data import open_dataset

    folder, _ = tiny_eval
    ds = open_dataset(folder)
    monkeypatch.setenv("SAMP_RUNS_DIR", str(tmp_path / "runs"))
    assert main(["planner=straight", f"dataset={folder}", "splits=[val]", "record=false", "benchmark=null"]) == 0
    assert (tmp_path / "runs" / "eval" / f"straight_{ds.name}@{ds.id}" / METRICS_JSON).is_file(), _error(capsys)


def test_the_test_scenes_of_the_run_s_own_dataset_can_be_evaluated(tiny_eval, tmp_path, capsys, fake_policy_package,
                                                                 panda):
    """Test scenes of the training dataset are unseen by construction (no demonstrations), so they pass the
    content-hash check; the benchmark can be skipped."""
    run = _run_folder(tmp_path, tiny_eval[0], asset_hash=panda.asset_hash)
    assert main([f"run={run}", "splits=[test]", "record=false", "benchmark=null"]) == 0, _error(capsys)
    report = json.loads((run / "eval" / METRICS_JSON).read_text())
    assert set(report["groups"]) == {"test", "test_hard"} and report["groups"]["test"]["problems"] == 3


def test_a_run_folder_without_a_checkpoint_is_refused(tiny_eval, tmp_path, capsys):
    run = _run_folder(tmp_path, tiny_eval[0], checkpoint=False)
    assert main([f"run={run}"]) == 2
    err = _error(capsys)
    assert "no checkpoint to evaluate" in err and "best.ckpt or last.ckpt" in err and str(run / "checkpoints") in err
    assert main([f"run={tmp_path / 'nowhere'}"]) == 2
    assert "does not exist" in _error(capsys)


def test_a_checkpoint_without_the_policy_package_says_so(tiny_eval, tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "samp.policy", None)  # as if samp.policy did not exist
    run = _run_folder(tmp_path, tiny_eval[0])
    assert main([f"run={run}", "record=false"]) == 2
    assert "policy package (samp.policy with load_policy) is not available" in _error(capsys)


def test_a_checkpoint_for_another_robot_is_refused(tiny_eval, tmp_path, capsys, fake_policy_package, robots):
    run = _run_folder(tmp_path, tiny_eval[0], robot="iiwa")
    assert main([f"run={run}"]) == 2
    err = _error(capsys)
    assert "policy for robot 'iiwa'" in err and "is for 'panda'" in err
    other = _run_folder(tmp_path / "b", tiny_eval[0], asset_hash="0" * 64)
    assert main([f"run={other}"]) == 2
    assert "different URDF or meshes" in _error(capsys)
    assert fake_policy_package == [], "nothing is loaded for a robot that run.json says is another"
    silent = _run_folder(tmp_path / "c", tiny_eval[0], robot=None)  # run.json names no robot: the policy does
    fake_policy_package.module.load_policy.robot = robots["iiwa"]
    assert main([f"run={silent}"]) == 2
    assert "the policy is for robot 'iiwa', but dataset tiny_eval" in _error(capsys)


@pytest.fixture(scope="module")
def no_heldout(tmp_path_factory, _isolated_cache):
    from samp.data import generate

    spec = {"name": "no_heldout", "robot": "panda", "seed": 3, "train_scenes": 1, "val_scenes": 0,
            "trajectories_per_scene": 2, "eval_problems_per_scene": 2, "generators": ["tabletop"], "resolutions": [12]}
    return generate(spec, root=tmp_path_factory.mktemp("no_heldout"), progress=False)


def test_a_dataset_without_validation_scenes_is_refused(no_heldout, tmp_path, capsys):
    for split in ("split=heldout", "split=both", "splits=[val]"):
        assert main(["planner=straight", f"dataset={no_heldout}", split, f"out={tmp_path}", "benchmark=null"]) == 2
        err = _error(capsys)
        assert "has no val scenes" in err and "splits=[train]" in err, err
    assert main(["planner=straight", f"dataset={no_heldout}", "splits=[train]", f"out={tmp_path}", "record=false",
                 "benchmark=null"]) == 0


def test_unknown_keys_and_missing_choices_are_refused(tiny_eval, tmp_path, capsys):
    assert main(["planner=expert", f"dataset={tiny_eval[0]}", "+bogus=1"]) == 2
    assert "unknown eval setting 'bogus'" in (err := _error(capsys)) and "valid keys: run, planner, dataset" in err
    assert main(["planner=expert", f"dataset={tiny_eval[0]}", "bogus=1"]) == 2
    assert "valid keys: run, planner, dataset" in _error(capsys)
    assert main([f"dataset={tiny_eval[0]}"]) == 2
    assert "say what to evaluate" in _error(capsys)
    assert main(["planner=magic", f"dataset={tiny_eval[0]}"]) == 2
    assert "planner must be expert | straight" in _error(capsys)
    assert main(["planner=expert"]) == 2
    assert "say which dataset" in _error(capsys)


def test_the_composed_config_is_re_merged_strictly():
    from samp.eval.config import load_eval_config

    with pytest.raises(ValueError, match="Key 'bogus' not in 'EvalConfig'.*Valid keys: run, planner"):
        load_eval_config({"bogus": 1})
    with pytest.raises(ValueError, match=r"splits must be a list of distinct train \| val \| test"):
        load_eval_config({"splits": ["validation"]})
    with pytest.raises(ValueError, match="unknown benchmark 'nowhere'.*benchmarks: .*unseen"):
        from samp.eval.benchmark import benchmark_spec

        benchmark_spec("nowhere")


@pytest.fixture(scope="module")
def test_scenes_only(tmp_path_factory, _isolated_cache):
    """A dataset of unseen scenes and their evaluation problems only, no demonstrations (as a benchmark is)."""
    from samp.data import generate

    spec = {"name": "test_only", "robot": "panda", "seed": 5, "train_scenes": 0, "val_scenes": 0, "test_scenes": 1,
            "trajectories_per_scene": 0, "eval_problems_per_scene": 2, "generators": ["tabletop"], "resolutions": [12]}
    return generate(spec, root=tmp_path_factory.mktemp("test_only"), progress=False)


def test_a_dataset_without_demonstrations_can_be_evaluated(test_scenes_only, tmp_path, capsys, fake_policy_package,
                                                           panda):
    """A dataset with no demonstrations (len 0, so falsy) is still the dataset evaluated, not skipped for a
    benchmark that was switched off (this once raised UnboundLocalError)."""
    from samp.data import open_dataset

    problems = len(open_dataset(test_scenes_only).eval_problems)
    run = _run_folder(tmp_path, test_scenes_only, asset_hash=panda.asset_hash)
    args = [f"run={run}", f"dataset={test_scenes_only}", "splits=[test]", "problems=null", "record=false",
            "benchmark=null"]
    assert main(args) == 0, _error(capsys)
    report = json.loads((run / "eval" / METRICS_JSON).read_text())
    assert problems >= 1 and report["groups"]["test"]["problems"] == problems
