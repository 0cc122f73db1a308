"""The Table III evaluation: metrics on known errors, ground truth against brute force, fixed held-out
sets, and the files it writes (tables and a Rerun recording that the rerun CLI verifies)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from samp.robot_sdf.evaluate import (SDFEvalConfig, _link_poses, error_metrics, evaluate_methods, heldout_link_set,
                                     robot_signed_distance)
from samp.robot_sdf.samples import link_signed_distance

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

RERUN = Path(sys.executable).parent / "rerun"


def test_error_metrics_split_by_true_distance():
    truth = np.array([0.01, -0.02, 0.06, 0.10, 0.20])
    pred = truth + np.array([0.001, -0.003, 0.002, 0.0, 0.01])
    m = error_metrics(pred, truth)
    assert m["count_all"] == 5 and m["count_near"] == 2 and m["count_far"] == 2
    np.testing.assert_allclose(m["mae_near_mm"], 2.0)
    np.testing.assert_allclose(m["mae_far_mm"], 1.0)
    np.testing.assert_allclose(m["rmse_all_mm"], np.sqrt((1 + 9 + 4 + 0 + 100) / 5))


def test_robot_ground_truth_is_the_min_over_links(panda):
    q = np.array([panda.home.double().numpy(), np.zeros(7) + 0.3])
    poses = _link_poses(panda, q)
    rng = np.random.default_rng(0)
    for pose in poses:
        points = rng.uniform([-0.6, -0.6, -0.1], [0.6, 0.6, 1.1], size=(400, 3))
        brute = np.min([link_signed_distance(panda.geometry[n], (points - T[:3, 3]) @ T[:3, :3])
                        for n, T in zip(panda.link_names, pose)], axis=0)
        np.testing.assert_allclose(robot_signed_distance(panda, points, pose), brute, atol=1e-12)


def test_heldout_sets_are_fixed_by_the_seed(panda, panda_samples, tmp_path, monkeypatch):
    _, s = panda_samples
    cfg = SDFEvalConfig(link_points=100, configs=2, robot_points=50)
    a = heldout_link_set(panda, s.centres, s.scales, cfg)
    monkeypatch.setenv("SAMP_CACHE_DIR", str(tmp_path))  # recomputed, not read from the cache
    b = heldout_link_set(panda, s.centres, s.scales, cfg)
    np.testing.assert_array_equal(a["points"], b["points"])
    c = heldout_link_set(panda, s.centres, s.scales, SDFEvalConfig(link_points=100, configs=2, robot_points=50, seed=1))
    assert not np.array_equal(a["points"], c["points"])
    near = np.abs(a["sdf"]) < 0.05
    assert 0.5 < near.mean() < 1.0 and (a["link"] == 0).sum() == 100


def test_evaluate_methods_writes_the_table_and_a_valid_recording(panda, panda_samples, tmp_path):
    from samp.robot_sdf.baselines import fit_bernstein
    from samp.robot_sdf.whole_robot import RobotSDF

    _, s = panda_samples
    net, _ = fit_bernstein(s, 8)
    model = RobotSDF(panda, net, s.centres, s.scales, method=net.label)
    cfg = SDFEvalConfig(link_points=200, configs=2, robot_points=200, timing_batches=[1], recording_spacing=0.03)
    report = evaluate_methods(panda, {net.label: {"model": model, "train_time_s": 1.5}}, cfg, tmp_path)
    res = report["methods"]["RDF (N=8)"]
    assert res["whole_robot"]["mae_all_mm"] < 5 and res["per_link"]["mae_near_mm"] < 5, res
    assert set(res["infer_ms"]) == {"1"} and res["train_time_s"] == 1.5
    md = (tmp_path / "robot_sdf_table.md").read_text()
    assert "| RDF (N=8) |" in md and "## Whole robot" in md and "## Per link" in md and "| SAMP | 3.3 |" in md
    assert json.loads((tmp_path / "robot_sdf_table.json").read_text())["robot"] == "panda"
    rrd = tmp_path / "robot_sdf.rrd"
    verify = subprocess.run([str(RERUN), "rrd", "verify", str(rrd)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    printed = subprocess.run([str(RERUN), "rrd", "print", str(rrd)], capture_output=True, text=True, timeout=120).stdout
    for entity in ("/sdf/ground_truth/slice_0/bands", "/sdf/RDF_N_8/slice_1/levels/30mm", "/robot/links/panda_hand"):
        assert entity in printed, f"{entity} missing from the recording"
