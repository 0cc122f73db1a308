"""The faults "run.json's dataset edited, or dataset= given" and "files_sha256 removed from run.json, another
run's checkpoint copied in", replayed with `python -m samp.eval` on a real policy checkpoint (an untrained
SAMP system bound to a dataset, saved with its binding): another dataset than the checkpoint's own is
refused unless allow_other_dataset=true, which the results then record (and its train split is refused
even then); a checkpoint its run's record does not cover is evaluated, said loudly once, and marked
unverified in metrics.json and metrics.md."""

from __future__ import annotations

import json

import pytest
import torch

from samp.eval.__main__ import main

pytestmark = pytest.mark.slow  # generates the tiny evaluation dataset and evaluates through the CLI

SMALL_NET = {"channels": 2, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}
ARGS = ["splits=[val]", "problems=1", "record=false", "benchmark=null", "timed_problems=0", "max_steps=3",
        "compare_expert=false", "device=cpu"]


def _checkpoint(path, dataset_id: str, robots, small_robot_sdf, seed: int = 0):
    """A SAMP policy checkpoint (untrained weights) bound to `dataset_id` at n_e = 12."""
    from samp.data.binding import DatasetBinding
    from samp.policy.system import PolicySystem
    from samp.scene.model import DEFAULT_BOUNDS

    panda = robots["panda"]
    torch.manual_seed(seed)
    system = PolicySystem(robot="panda", robot_sdf_payload=small_robot_sdf(panda), model=SMALL_NET)
    with torch.no_grad():  # the network's initialisation may not follow torch's seed: make the weights differ
        next(system.parameters()).add_(float(seed))
    system.bind(DatasetBinding("panda", panda.asset_hash, dataset_id, 12, DEFAULT_BOUNDS))
    ckpt = {"state_dict": system.state_dict(), "hyper_parameters": dict(system.hparams)}
    system.on_save_checkpoint(ckpt)
    path.parent.mkdir(parents=True, exist_ok=True)
    torch.save(ckpt, path)
    return path


def _run(tmp_path, name: str, dataset, dataset_id: str, robots, small_robot_sdf, hashes: bool = True):
    """A finished run folder: checkpoints/last.ckpt bound to `dataset_id`, run.json naming `dataset`."""
    from samp.integrity import hash_run_files

    run = tmp_path / name
    _checkpoint(run / "checkpoints" / "last.ckpt", dataset_id, robots, small_robot_sdf)
    record = {"status": "completed", "dataset": str(dataset), "robot": {"name": "panda"}}
    if hashes:
        (run / "run.json").write_text("{}")
        record["files_sha256"] = hash_run_files(run)
    (run / "run.json").write_text(json.dumps(record))
    return run


@pytest.fixture(scope="module")
def tiny(tiny_eval):
    from samp.data import open_dataset

    ds = open_dataset(tiny_eval[0])
    return tiny_eval[0], f"{ds.name}@{ds.id}"


def test_a_run_on_its_own_dataset_is_evaluated_whole(tiny, tmp_path, capsys, robots, small_robot_sdf):
    folder, own = tiny
    run = _run(tmp_path, "own", folder, own, robots, small_robot_sdf)
    assert main([f"run={run}", *ARGS]) == 0, capsys.readouterr().err
    assert "warning" not in capsys.readouterr().err
    report = json.loads((run / "eval" / "metrics.json").read_text())
    assert (report["trained_on"], report["evaluated_on"], report["other_dataset"], report["unverified"]) == \
        (own, own, False, None)
    assert "Unverified" not in (run / "eval" / "metrics.md").read_text()


def test_another_dataset_than_the_checkpoint_s_is_refused_unless_allowed(tiny, tmp_path, capsys, robots,
                                                                          small_robot_sdf):
    """run.json names the tiny dataset (as if its dataset had been edited), but the checkpoint was trained on
    another one: refused, naming both; `dataset=` naming it is refused the same way. allow_other_dataset=true
    evaluates it, records it, and still refuses the train split."""
    folder, given = tiny
    trained = "tiny_eval@0123456789ab"
    run = _run(tmp_path, "edited", folder, trained, robots, small_robot_sdf)
    for extra in ([], [f"dataset={folder}"]):
        assert main([f"run={run}", *ARGS, *extra]) == 2
        err = capsys.readouterr().err
        assert f"was trained on dataset {trained}, not {given}" in err and "allow_other_dataset=true" in err, err
        assert len(err.strip().splitlines()) == 1, err
    assert not (run / "eval").exists(), "nothing is written for a refused evaluation"
    assert main([f"run={run}", *ARGS, "allow_other_dataset=true", "splits=[val,train]"]) == 2
    assert f"never trained on the training scenes of {given}" in capsys.readouterr().err
    assert main([f"run={run}", *ARGS, "allow_other_dataset=true"]) == 0, capsys.readouterr().err
    report = json.loads((run / "eval" / "metrics.json").read_text())
    assert (report["trained_on"], report["evaluated_on"], report["other_dataset"]) == (trained, given, True)
    assert f"the policy trained on {trained} and is evaluated on {given}" in (run / "eval" / "metrics.md").read_text()


def test_a_checkpoint_without_recorded_hashes_is_marked_unverified(tiny, tmp_path, capsys, robots, small_robot_sdf):
    """files_sha256 removed from run.json and another run's checkpoint (same dataset) copied in: evaluated, the
    warning printed once, and the results marked unverified. With the record in place, the copied checkpoint
    is refused by its hash."""
    folder, own = tiny
    run = _run(tmp_path, "stripped", folder, own, robots, small_robot_sdf, hashes=False)
    _checkpoint(run / "checkpoints" / "last.ckpt", own, robots, small_robot_sdf, seed=1)  # another run's weights
    assert main([f"run={run}", *ARGS]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: ") == 1 and "records no files_sha256" in err, err
    report = json.loads((run / "eval" / "metrics.json").read_text())
    assert "records no files_sha256" in report["unverified"]
    assert "**Unverified:**" in (run / "eval" / "metrics.md").read_text()
    recorded = _run(tmp_path, "recorded", folder, own, robots, small_robot_sdf)
    _checkpoint(recorded / "checkpoints" / "last.ckpt", own, robots, small_robot_sdf, seed=1)
    assert main([f"run={recorded}", *ARGS]) == 2
    assert "is not the file its run recorded" in capsys.readouterr().err
