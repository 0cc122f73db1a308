"""An evaluation override cannot bypass a policy's own checks (issue 21): `samp.eval run=R n_e=N` for a
policy trained at another n_e is refused, naming what the policy needs, before anything is rolled out."""

from __future__ import annotations

import json

import pytest
import torch

from samp.eval.__main__ import main

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SMALL_NET = {"channels": 2, "env_hidden": [32], "point_hidden": [16, 32], "config_hidden": [16], "fusion_hidden": [32]}


@pytest.fixture(scope="module")
def trained_run(tiny_eval, tmp_path_factory, panda, small_robot_sdf):
    """A run folder holding a real policy checkpoint, fitted two steps at n_e = 16 on the tiny dataset."""
    import pytorch_lightning as pl

    from samp.data.module import TrajectoryDataModule
    from samp.policy.system import PolicySystem

    folder, _ = tiny_eval
    dm = TrajectoryDataModule(str(folder), n_e=16, batch_size=8, noise=0.0)
    system = PolicySystem(robot="panda", robot_sdf_payload=small_robot_sdf(panda), model=SMALL_NET)
    trainer = pl.Trainer(max_steps=2, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(system, datamodule=dm)
    run = tmp_path_factory.mktemp("override_run")
    (run / "checkpoints").mkdir()
    trainer.save_checkpoint(run / "checkpoints" / "last.ckpt")
    (run / "run.json").write_text(json.dumps({"status": "completed", "dataset": str(folder), "robot": "panda"}))
    return run


def test_an_n_e_override_that_contradicts_the_policy_is_refused(trained_run, tmp_path, capsys):
    from samp.policy import load_policy

    assert load_policy(trained_run / "checkpoints" / "last.ckpt").n_e == 16  # what the policy itself says
    out = tmp_path / "eval"
    code = main([f"run={trained_run}", "n_e=12", "benchmark=null", f"out={out}"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "n_e=12 contradicts the policy" in err and "n_e = 16" in err and "n_e=16" in err, err
    assert not (out / "metrics.json").exists()


def test_the_policy_s_own_n_e_is_accepted(trained_run, tmp_path, capsys):
    out = tmp_path / "eval"
    code = main([f"run={trained_run}", "n_e=16", "benchmark=null", "splits=[val]", "problems=1", "record_rollouts=0",
                 "compare_expert=false", "timed_problems=0", f"out={out}"])
    assert code == 0, capsys.readouterr().err
    assert (out / "metrics.json").is_file()


def _copy_with_hash(trained_run, tmp_path):
    """A copy of the run whose run.json records its checkpoint's sha256, as a finished run's does."""
    import hashlib
    import shutil

    run = shutil.copytree(trained_run, tmp_path / "run")
    record = json.loads((run / "run.json").read_text())
    ckpt = run / "checkpoints" / "last.ckpt"
    record["files_sha256"] = {"checkpoints/last.ckpt": hashlib.sha256(ckpt.read_bytes()).hexdigest()}
    (run / "run.json").write_text(json.dumps(record))
    return run, ckpt


def test_a_flipped_byte_in_the_checkpoint_is_refused_by_the_evaluation(trained_run, tmp_path, capsys):
    run, ckpt = _copy_with_hash(trained_run, tmp_path)
    data = bytearray(ckpt.read_bytes())
    data[len(data) // 2] ^= 0x01
    ckpt.write_bytes(bytes(data))
    assert main([f"run={run}", "benchmark=null", f"out={tmp_path / 'eval'}"]) == 2
    err = capsys.readouterr().err
    assert f"{ckpt} is not the file its run recorded: sha256 expected" in err, err


def test_a_crafted_checkpoint_in_a_run_folder_runs_no_code(trained_run, tmp_path, capsys):
    """Whoever owns the run folder can also record the crafted file's hash: loading must still refuse it."""
    marker = tmp_path / "pwned"

    class Planted:
        def __reduce__(self):
            return (open, (str(marker), "w"))

    run, ckpt = _copy_with_hash(trained_run, tmp_path)
    good = torch.load(ckpt, weights_only=True)
    torch.save({**good, "planted": Planted()}, ckpt)
    run_json = json.loads((run / "run.json").read_text())
    import hashlib

    run_json["files_sha256"]["checkpoints/last.ckpt"] = hashlib.sha256(ckpt.read_bytes()).hexdigest()
    (run / "run.json").write_text(json.dumps(run_json))
    assert main([f"run={run}", "benchmark=null", f"out={tmp_path / 'eval'}"]) == 2
    err = capsys.readouterr().err
    assert "was refused" in err and "trust_checkpoint=true" in err, err
    assert not marker.exists(), "evaluating the run ran the checkpoint's code"
