"""A robot SDF trained for a few seconds through the real CLI: the loss falls, the artifacts are written,
the whole-robot query is the min over links, culling changes nothing, signs and the zero level set
follow the meshes (to the accuracy of a seconds-long training), and bad input is refused."""

from __future__ import annotations

import csv
import os
import subprocess
import sys

import numpy as np
import pytest
import torch
import trimesh

from samp.robot_sdf import load_robot_sdf
from samp.robot_sdf.samples import link_signed_distance


@pytest.fixture(scope="module")
def run_dir(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("robot_sdf")
    cmd = [sys.executable, "-m", "samp.train", "+experiment=robot_sdf_panda", "robot_sdf_samples=tiny",
           "robot_sdf_eval=tiny", "trainer.max_steps=250", "datamodule.steps_per_epoch=50",
           "trainer.log_every_n_steps=10", "trainer.enable_progress_bar=false", f"paths.runs_dir={tmp / 'runs'}",
           f"paths.datasets_dir={tmp / 'datasets'}"]
    out = subprocess.run(cmd, capture_output=True, text=True, timeout=900, env={**os.environ, "RERUN_ANALYTICS": "0"})
    assert out.returncode == 0, out.stderr[-3000:]
    (run,) = (tmp / "runs" / "robot_sdf_panda").iterdir()
    return run


def test_cli_training_improves_the_loss_and_writes_the_artifacts(run_dir):
    rows = [r for r in csv.DictReader(open(run_dir / "metrics.csv")) if r.get("train/loss")]
    losses = [float(r["train/loss"]) for r in rows]
    assert len(losses) >= 3 and losses[-1] < losses[0] / 5, losses
    for name in ("robot_sdf.pt", "robot_sdf_table.md", "robot_sdf_table.json", "robot_sdf.rrd", "run.json"):
        assert (run_dir / name).is_file(), name
    assert '"status": "completed"' in (run_dir / "run.json").read_text()


@pytest.fixture(scope="module")
def model(run_dir):
    return load_robot_sdf(run_dir, dtype=torch.float64)


def _points_around_robot(model, B: int = 3, N: int = 600, seed: int = 0):
    g = torch.Generator().manual_seed(seed)
    lo, hi = model.robot.joint_limits.T
    q = lo + (hi - lo) * torch.rand(B, model.robot.dof, generator=g, dtype=torch.float64)
    centre = model.robot.transform_points(q).mean(dim=1, keepdim=True)
    pts = centre + 0.5 * (2 * torch.rand(B, N, 3, generator=g, dtype=torch.float64) - 1)
    return pts, q


def test_whole_robot_query_is_the_min_over_links_and_culling_changes_nothing(model):
    pts, q = _points_around_robot(model)
    per_link = model.link_distances(pts, q)
    full = model.query(pts, q, cull=False)
    culled = model.query(pts, q)
    torch.testing.assert_close(full, per_link.min(dim=-1).values, rtol=0, atol=0)
    assert float((culled - full).detach().abs().max()) <= 1e-6


def test_gradient_with_respect_to_points(model):
    pts, q = _points_around_robot(model, B=1, N=50)
    pts.requires_grad_()
    model.query(pts, q).sum().backward()
    assert torch.isfinite(pts.grad).all() and pts.grad.abs().sum() > 0


def test_signs_and_zero_level_set_follow_each_link(model):
    robot = model.robot
    rng = np.random.default_rng(0)
    for i, name in enumerate(robot.link_names):
        mesh: trimesh.Trimesh = robot.link_meshes[name]
        surface, _ = trimesh.sample.sample_surface(mesh, 300, seed=1)
        lo, hi = mesh.bounds
        box = rng.uniform(lo - 0.06, hi + 0.06, size=(3000, 3))
        truth = link_signed_distance(robot.geometry[name], box)
        link = torch.full((len(box),), i)
        pred = model.local_distance(torch.from_numpy(box), link).detach().numpy()
        clear = np.abs(truth) > 0.02  # beyond twice the short training's typical error
        assert np.mean(np.sign(pred[clear]) == np.sign(truth[clear])) > 0.97, name
        zero = model.local_distance(torch.from_numpy(surface), torch.full((len(surface),), i)).detach().numpy()
        assert np.median(np.abs(zero)) < 0.01, f"{name}: zero level set {np.median(np.abs(zero)) * 1000:.1f} mm off"


def test_bad_input_is_refused(model, run_dir):
    pts, q = _points_around_robot(model, B=2, N=4)
    with pytest.raises(ValueError, match=r"points must have shape \(B, N, 3\)"):
        model.query(pts[0], q)
    with pytest.raises(ValueError, match=r"q must have shape \(B, 7\)"):
        model.query(pts, q[:, :6])
    with pytest.raises(ValueError, match="trained for robot 'panda', not 'iiwa'"):
        load_robot_sdf(run_dir, robot="iiwa")
