"""Small lies of a training run refused before anything is made (issue 52): `trainer.max_steps=0` (or
`max_epochs=0`) would record an untrained run as completed; a `datamodule.n_e` the dataset stores no grids
at was refused only after the run folder and the tracker run existed, with advice naming a key that does
not exist. Both are one line from the command, with no run folder; the advice's keys are real (the
command it suggests composes and runs)."""

from __future__ import annotations

import json

import pytest

from samp.data.registry import finalize_dataset
from samp.train import compose_train_config


@pytest.mark.parametrize("key", ["max_steps", "max_epochs"])
def test_a_run_that_trains_nothing_is_refused_when_composed(key):
    with pytest.raises(ValueError, match=rf"trainer\.{key}=0 trains nothing.*give trainer\.{key}=N with N >= 1"):
        compose_train_config(["experiment=quickstart", f"trainer.{key}=0"])
    compose_train_config(["experiment=quickstart", f"trainer.{key}=1"])  # one step is a run


def _stand_in(root, name: str, resolutions: list[int]):
    """A dataset folder whose manifest says it stores grids at `resolutions` (what the check reads)."""
    tmp = root / ".tmp-build"
    tmp.mkdir(parents=True)
    (tmp / "scene_0000.mcap").write_bytes(b"stand-in")
    return finalize_dataset(tmp, name, {"config": {"resolutions": resolutions}, "counts": {"eval_problems": 1}}, root)


def test_a_resolution_the_dataset_lacks_is_refused_before_the_run_folder(tmp_path, monkeypatch, capsys):
    from samp.train.cli import main

    datasets, runs = tmp_path / "datasets", tmp_path / "runs"
    folder = _stand_in(datasets, "smoke", [16])
    monkeypatch.setenv("SAMP_RUNS_DIR", str(runs))
    monkeypatch.setenv("SAMP_TRACKING_URI", "off")
    args = ["experiment=mpnet", "datamodule.dataset=smoke", f"datamodule.root={datasets}", "datamodule.n_e=40",
            "evaluation.benchmark=null"]
    assert main(args) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert f"smoke@{folder.name} stores anchor grids at n_e in [16], not 40: set datamodule.n_e=16" in err[0], err
    assert not runs.exists() or not any(runs.rglob("*")), f"made before the refusal: {list(runs.rglob('*'))}"
    # the keys it names are real: datamodule.n_e composes, and the suggested generate command's override too
    assert compose_train_config(["experiment=mpnet", "datamodule.n_e=16"]).datamodule.n_e == 16
    suggested = err[0].rsplit(": ", 1)[1]
    assert suggested == "python -m samp.data generate dataset=smoke dataset.resolutions=[16,40]", suggested
    from samp.data.__main__ import _config

    assert list(_config(suggested.split()[4:])["dataset"]["resolutions"]) == [16, 40]


def test_a_stored_resolution_passes_the_check(tmp_path):
    from omegaconf import OmegaConf

    from samp.train.prerequisites import _check_resolution

    manifest = json.loads((_stand_in(tmp_path, "mine", [16, 40]) / "manifest.json").read_text())
    _check_resolution(OmegaConf.create({"datamodule": {"n_e": 40}}), manifest)
    _check_resolution(OmegaConf.create({"datamodule": {"n_e": 40}}), {"config": {}})  # older manifests: not here
