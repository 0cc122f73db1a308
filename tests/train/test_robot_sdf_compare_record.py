"""The Table III comparison run records what traces its numbers back (issue 21): the seed of the network
runs, the evaluation's seed, and the resolved config (RDF settings, evaluation sizes, each network run's
resolved config)."""

from __future__ import annotations

import json
import os

import pytest

from samp.train.robot_sdf_compare import compare_methods

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

TINY_SDF = ["robot_sdf_samples=tiny", "datamodule.steps_per_epoch=5", "datamodule.near_per_step=128",
            "datamodule.uniform_per_step=64", "trainer.enable_progress_bar=false", "trainer.max_steps=5",
            "seed=3"]
EVAL = {"link_points": 200, "configs": 2, "robot_points": 200, "timing_batches": [1], "recording": False, "seed": 11}


def test_the_comparison_run_records_seed_and_resolved_config(tmp_path, monkeypatch):
    monkeypatch.setenv("SAMP_DATASETS_DIR", str(tmp_path / "datasets"))
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    _, folder = compare_methods("panda", TINY_SDF, rdf={8: {}}, evaluation=EVAL, runs_root=tmp_path / "runs")
    record = json.loads((folder / "run.json").read_text())
    assert record["status"] == "completed" and record["seed"] == 3 and record["evaluation_seed"] == 11
    config = record["config"]
    assert config["overrides"] == TINY_SDF and config["rdf"] == {"8": {}}
    assert config["evaluation"]["link_points"] == 200 and config["evaluation"]["seed"] == 11
    networks = config["networks"]
    assert len(networks) == 2 and all(c["seed"] == 3 and c["trainer"]["max_steps"] == 5 for c in networks.values())
    for method, run in record["runs"].items():
        if "run_dir" in run:
            network = json.loads((tmp_path / "runs" / os.path.relpath(run["run_dir"], tmp_path / "runs") / "run.json")
                                 .read_text())
            assert network["config"] == networks[method]
