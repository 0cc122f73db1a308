"""Checkpoints and artifacts carry their sha256 in run.json and are checked on load; nothing a user points
at runs code when loaded (docs/design.md section 7; issue 21): a flipped byte in a checkpoint or an artifact, a
truncated checkpoint, and a crafted checkpoint whose unpickling would write a marker file, through the
Python API and through `samp.train resume=...`."""

from __future__ import annotations

import fractions
import hashlib
import json
import os
import shutil

import pytest
import torch

from samp.integrity import IntegrityError
from samp.policy.registry import read_checkpoint
from samp.robot_sdf import load_robot_sdf

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


@pytest.fixture(scope="module")
def finished(tmp_path_factory, cli, tiny_sdf):
    """A finished tiny robot SDF run: (runs folder, run folder)."""
    runs = tmp_path_factory.mktemp("integrity_runs")
    done = cli("samp.train", ["+experiment=robot_sdf_panda", "trainer.max_steps=20", *tiny_sdf], runs)
    assert done.returncode == 0, done.stdout[-2000:] + done.stderr[-3000:]
    (folder,) = (runs / "robot_sdf_panda").iterdir()
    return runs, folder


@pytest.fixture
def copy(finished, tmp_path):
    return shutil.copytree(finished[1], tmp_path / "runs" / "robot_sdf_panda" / finished[1].name)


def _flip(path, where: float = 0.5) -> None:
    data = bytearray(path.read_bytes())
    data[int(len(data) * where)] ^= 0x01
    path.write_bytes(bytes(data))


def _sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


class _Planted:
    """Unpickling this calls code of its choosing: here it creates the marker file."""

    def __init__(self, marker: str):
        self.marker = marker

    def __reduce__(self):
        return (open, (self.marker, "w"))  # creating the file is the proof that code ran


def _record_hash(folder, rel: str) -> None:
    """What whoever planted a file in their own run folder can do: record its hash too."""
    record = json.loads((folder / "run.json").read_text())
    record["files_sha256"][rel] = _sha(folder / rel)
    (folder / "run.json").write_text(json.dumps(record))


def test_run_json_records_the_sha256_of_checkpoints_and_artifacts(finished):
    _, folder = finished
    record = json.loads((folder / "run.json").read_text())
    assert record["status"] == "completed"
    want = {"checkpoints/last.ckpt": _sha(folder / "checkpoints" / "last.ckpt"), "robot_sdf.pt": _sha(folder / "robot_sdf.pt")}
    assert {k: record["files_sha256"].get(k) for k in want} == want


@pytest.mark.parametrize("rel", ["robot_sdf.pt", "checkpoints/last.ckpt"])
def test_a_flipped_byte_is_refused_naming_the_file(copy, rel):
    load_robot_sdf(copy / rel)  # intact: loads
    _flip(copy / rel)
    with pytest.raises(IntegrityError, match=rf"{rel} is not the file its run recorded: sha256 expected [0-9a-f]{{64}} .* "
                                              r"actual [0-9a-f]{64}"):
        load_robot_sdf(copy if rel == "robot_sdf.pt" else copy / rel)
    with pytest.raises(IntegrityError, match="is not the file its run recorded"):
        read_checkpoint(copy / rel)


def test_resume_from_a_flipped_checkpoint_is_refused(copy, cli, tiny_sdf):
    _flip(copy / "checkpoints" / "last.ckpt")
    out = cli("samp.train", [f"resume={copy}", "trainer.max_steps=40"], copy.parent.parent)
    assert out.returncode == 2, out.stdout[-2000:] + out.stderr[-2000:]
    assert "last.ckpt is not the file its run recorded: sha256 expected" in out.stderr
    assert json.loads((copy / "run.json").read_text())["status"] == "completed", "the refused resume changed the record"


def test_a_truncated_checkpoint_names_the_file(copy):
    path = copy / "checkpoints" / "last.ckpt"
    path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    _record_hash(copy, "checkpoints/last.ckpt")  # so the hash check passes and loading itself is what fails
    with pytest.raises(IntegrityError, match=rf"{path} is not a readable policy checkpoint: .* truncated or damaged"):
        read_checkpoint(path)


def test_a_crafted_checkpoint_runs_no_code(copy, tmp_path, cli, tiny_sdf):
    """A checkpoint whose unpickling would create a marker file is refused by the loader, by resuming and
    by the robot SDF loader; the marker never appears. The opt-in message is named."""
    marker = tmp_path / "pwned"
    path = copy / "checkpoints" / "last.ckpt"
    good = torch.load(path, weights_only=True)
    torch.save({**good, "samp": {"kind": "samp"}, "hyper_parameters": {"x": _Planted(str(marker))}}, path)
    _record_hash(copy, "checkpoints/last.ckpt")
    with pytest.raises(IntegrityError, match=r"refused: .*trust_checkpoint=true .*SAMP_TRUST_CHECKPOINTS=1"):
        read_checkpoint(path)
    with pytest.raises(ValueError):
        load_robot_sdf(path)
    out = cli("samp.train", [f"resume={copy}", "trainer.max_steps=40"], copy.parent.parent)
    assert out.returncode == 2 and "refused" in out.stderr and "trust_checkpoint=true" in out.stderr, \
        out.stdout[-2000:] + out.stderr[-2000:]
    assert not marker.exists(), "loading the crafted checkpoint ran its code"


def test_trusting_a_checkpoint_is_an_explicit_opt_in(tmp_path, monkeypatch):
    """A file with a class outside the allow-list (harmless here) loads only when trusted."""
    path = tmp_path / "old.ckpt"
    torch.save({"state_dict": {}, "samp": {"kind": "samp"}, "hyper_parameters": {"ratio": fractions.Fraction(1, 3)}}, path)
    with pytest.raises(IntegrityError, match=r"Fraction.*trust_checkpoint=true"):
        read_checkpoint(path)
    assert read_checkpoint(path, trust_checkpoint=True)["hyper_parameters"]["ratio"] == fractions.Fraction(1, 3)
    monkeypatch.setenv("SAMP_TRUST_CHECKPOINTS", "1")
    assert read_checkpoint(path)["hyper_parameters"]["ratio"] == fractions.Fraction(1, 3)


def test_resume_of_an_intact_run_still_works(copy, cli):
    out = cli("samp.train", [f"resume={copy}", "trainer.max_steps=30"], copy.parent.parent)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    record = json.loads((copy / "run.json").read_text())
    assert record["status"] == "completed" and record["steps"] == 30
    assert record["files_sha256"]["checkpoints/last.ckpt"] == _sha(copy / "checkpoints" / "last.ckpt")
    assert os.path.getsize(copy / "checkpoints" / "last.ckpt") > 0


def test_lightning_resume_itself_refuses_a_crafted_checkpoint(tmp_path):
    """The recipe's resume path hands Lightning `weights_only=True` inside samp's allow-list
    (`recipe._safe_resume`): even without the recipe's own pre-check, Lightning refuses to unpickle the
    crafted file and its code never runs."""
    import pickle

    import pytorch_lightning as pl
    from omegaconf import OmegaConf
    from torch import nn

    from samp.train.recipe import _safe_resume

    class Tiny(pl.LightningModule):
        def __init__(self):
            super().__init__()
            self.layer = nn.Linear(2, 1)

        def training_step(self, batch, _):
            return self.layer(batch[0]).sum()

        def configure_optimizers(self):
            return torch.optim.SGD(self.parameters(), lr=0.1)

    data = torch.utils.data.DataLoader(torch.utils.data.TensorDataset(torch.zeros(4, 2)), batch_size=2)
    trainer = pl.Trainer(max_steps=1, logger=False, enable_progress_bar=False, enable_model_summary=False,
                         default_root_dir=tmp_path)
    trainer.fit(Tiny(), data)
    path = tmp_path / "last.ckpt"
    trainer.save_checkpoint(path)
    marker = tmp_path / "pwned"
    torch.save({**torch.load(path, weights_only=True), "planted": _Planted(str(marker))}, path)
    cfg = OmegaConf.create({"trust_checkpoint": False})
    again = pl.Trainer(max_steps=2, logger=False, enable_progress_bar=False, enable_model_summary=False,
                       default_root_dir=tmp_path)
    with pytest.raises(pickle.UnpicklingError), _safe_resume(path, cfg):
        again.fit(Tiny(), data, ckpt_path=str(path), weights_only=True)
    assert not marker.exists(), "Lightning ran the checkpoint's code"
