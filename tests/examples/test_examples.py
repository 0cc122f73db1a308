"""Every script in examples/ runs as a user would run it (a subprocess, small settings), and what it writes
is checked against an independent computation."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

REPO = Path(__file__).resolve().parents[2]


def _run(script: str, args: list[str], tmp_path: Path) -> str:
    env = {**os.environ, "PYTHONPATH": str(REPO), "OMP_NUM_THREADS": "1",
           "SAMP_DATASETS_DIR": str(tmp_path / "datasets"), "SAMP_RUNS_DIR": str(tmp_path / "runs")}
    out = subprocess.run([sys.executable, str(REPO / "examples" / script), *args], capture_output=True, text=True,
                         timeout=600, env=env, cwd=tmp_path)
    assert out.returncode == 0, out.stdout[-2000:] + out.stderr[-3000:]
    return out.stdout


def test_scene_and_grid(tmp_path):
    from samp.scene import Scene, anchor_points

    stdout = _run("scene_and_grid.py", ["--generator", "shelf", "--seed", "3", "--n-e", "12", "--out", "out"], tmp_path)
    scene = Scene.from_dict(json.loads((tmp_path / "out" / "scene.json").read_text()))
    grid = np.load(tmp_path / "out" / "grid.npy")
    assert grid.shape == (12, 12, 12) and "wrote" in stdout
    exact = np.asarray(scene.sdf(anchor_points(12, scene.bounds).numpy().reshape(-1, 3))).reshape(12, 12, 12)
    np.testing.assert_allclose(grid, exact, atol=1e-5)  # the saved grid is the scene's exact SDF at the anchors


def test_cloud_to_grid(tmp_path):
    from samp.perception import load_point_cloud

    stdout = _run("cloud_to_grid.py", ["--n-e", "12", "--out", "out"], tmp_path)
    cloud = load_point_cloud(tmp_path / "out" / "cloud.pcd")
    assert len(cloud) > 100 and f"{len(cloud)} points" in stdout
    assert np.load(tmp_path / "out" / "grid.npy").shape == (12, 12, 12)
    assert "against the exact grid: MAE near obstacles" in stdout


@pytest.mark.slow
def test_evaluate_run_on_a_benchmark(tmp_path):
    """The straight line on the smoke benchmark (generated on the way): the printed rate is the benchmark's
    stored problems' straight-line success, checked here with samp.eval directly."""
    stdout = _run("evaluate_run.py", ["straight", "--benchmark", "smoke"], tmp_path)
    assert "straight on bench_smoke@" in stdout and "8 problems, success" in stdout
    os.environ["SAMP_DATASETS_DIR"], old = str(tmp_path / "datasets"), os.environ.get("SAMP_DATASETS_DIR")
    try:
        from samp.eval import dataset_grids, evaluate, load_planner, problems_from_dataset
        from samp.eval.benchmark import open_benchmark

        bench = open_benchmark("smoke")
        result = evaluate(load_planner("straight", robot="panda"), problems_from_dataset(bench, "test", count=None, seed=0),
                          grids=dataset_grids(bench))
    finally:
        os.environ.pop("SAMP_DATASETS_DIR") if old is None else os.environ.__setitem__("SAMP_DATASETS_DIR", old)
    assert f"success {100 * result['metrics']['test']['success_rate']:.1f} %" in stdout
