"""`python -m samp.scene show`: the summary, a Rerun recording the rerun CLI can read, and the slice geometry."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from samp.scene import anchor_points, generate_scene
from samp.viz import anchor_stride, nearest_anchor_index, slice_quad, slice_values, zero_contour
from samp.scene.viz import QUAD_TRIANGLES

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

RERUN = Path(sys.executable).parent / "rerun"
BOUNDS = ((-1.0, -0.5, 0.05), (1.0, 0.7, 1.25))  # unequal spacings, so a swapped axis shows


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "RERUN_ANALYTICS": "0"}  # SAMP_CACHE_DIR: the session's temporary cache (conftest)
    return subprocess.run([sys.executable, "-m", "samp.scene", *args], capture_output=True, text=True,
                          timeout=300, env=env)


def _texcoord_to_world(corners: np.ndarray, texcoords: np.ndarray, t: np.ndarray) -> np.ndarray:
    """(P, 2) texture coordinates -> (P, 3) points, by barycentric interpolation in the quad's triangles
    (as a renderer maps a texture)."""
    out = np.full((len(t), 3), np.nan)
    for tri in QUAD_TRIANGLES:
        a, b, c = texcoords[tri]
        w12 = np.linalg.solve(np.stack([b - a, c - a], axis=1), (t - a).T).T  # (P, 2) weights of b and c
        w = np.concatenate([1 - w12.sum(1, keepdims=True), w12], axis=1)  # (P, 3)
        inside = (w >= -1e-12).all(1) & np.isnan(out[:, 0])
        out[inside] = w[inside] @ corners[tri]
    return out


@pytest.mark.parametrize("axis", [0, 1, 2])
def test_slice_pixels_land_on_their_anchors(axis):
    n_e = 5
    points = anchor_points(n_e, BOUNDS).numpy()  # (n, n, n, 3)
    grid = np.arange(n_e**3, dtype=np.float64).reshape(n_e, n_e, n_e)  # unique values, indexed (x, y, z)
    for index in (0, 2, n_e - 1):
        image = slice_values(grid, axis, index)  # (n_v, n_u)
        corners, texcoords = slice_quad(axis, index, n_e, BOUNDS)
        rows, cols = np.meshgrid(np.arange(n_e), np.arange(n_e), indexing="ij")
        centres = np.stack([(cols.ravel() + 0.5) / image.shape[1], (rows.ravel() + 0.5) / image.shape[0]], 1)
        world = _texcoord_to_world(corners, texcoords, centres)  # (n*n, 3)
        for (r, c), got in zip(zip(rows.ravel(), cols.ravel()), world):
            # The anchor whose value pixel [r, c] shows must sit where the texture puts that pixel.
            ijk = tuple(int(v) for v in np.argwhere(grid == image[r, c])[0])
            assert ijk[axis] == index, f"pixel {(r, c)} shows anchor {ijk}, off the slice {axis} = {index}"
            np.testing.assert_allclose(got, points[ijk], atol=1e-12,
                                       err_msg=f"axis {axis} index {index}: pixel {(r, c)} of anchor {ijk}")


def test_zero_contour_of_a_sphere_lies_on_the_sphere():
    n_e, centre, radius = 41, np.array([0.1, 0.05, 0.6]), 0.3
    points = anchor_points(n_e, BOUNDS).numpy()
    grid = np.linalg.norm(points - centre, axis=-1) - radius  # (n, n, n) exact sphere SDF
    spacing = (np.subtract(BOUNDS[1], BOUNDS[0]) / (n_e - 1)).max()
    for axis in range(3):
        index = int(nearest_anchor_index(centre, n_e, BOUNDS)[axis])
        strips = zero_contour(slice_values(grid, axis, index), axis, index, n_e, BOUNDS)
        assert len(strips) == 1, f"one closed circle expected on axis {axis}, got {len(strips)} lines"
        xyz = strips[0]  # (k, 3)
        plane = np.take(points[..., axis], index, axis=axis)  # (n, n), all the slice's coordinate
        np.testing.assert_allclose(xyz[:, axis], plane.flat[0], err_msg=f"contour off the slice plane {axis}")
        err = np.abs(np.linalg.norm(xyz - centre, axis=1) - radius).max()
        assert err < 0.05 * spacing, f"axis {axis}: contour off the sphere by {err:.2e} m (spacing {spacing:.3f})"


@pytest.mark.parametrize("n_e, max_points, stride", [(24, 50_000, 1), (64, 50_000, 2), (128, 50_000, 4), (3, 1, 3)])
def test_anchor_stride(n_e, max_points, stride):
    assert anchor_stride(n_e, max_points) == stride


def test_show_prints_summary_and_writes_recording(tmp_path):
    out = tmp_path / "shelf.rrd"
    proc = _run("show", "scene=shelf", "seed=1", "n_e=24", f"out={out}")
    assert proc.returncode == 0, proc.stderr
    text = proc.stdout
    scene = generate_scene("shelf", 1)
    grid = scene.anchor_grid(24).numpy()  # the CLI's own grid, from the shared cache
    assert "scene shelf_1: generator shelf, seed 1" in text, text
    assert f"content hash  {scene.content_hash()[:12]}" in text, text
    assert f"obstacles     {len(scene.obstacles)}: {len(scene.obstacles)} box" in text, text
    x, y, z = scene.target.pose.position
    assert f"target        box 'target' at ({x:.3f}, {y:.3f}, {z:.3f}) m" in text, text
    assert "anchors       n_e 24: 13824 anchors, spacing x 0.0870  y 0.0870  z 0.0522 m" in text, text
    inside = 100 * (grid < 0).mean()
    sdf_line = f"sdf           min {grid.min():.4f} m, max {grid.max():.4f} m; {inside:.2f}% of anchors inside"
    assert sdf_line in text, text
    assert "drawn         13824 of 13824 anchors as points (stride 1, at most 50000)" in text, text
    assert out.is_file() and out.stat().st_size > 10_000

    verify = subprocess.run([str(RERUN), "rrd", "verify", str(out)], capture_output=True, text=True, timeout=120)
    assert verify.returncode == 0, verify.stderr
    printed = subprocess.run([str(RERUN), "rrd", "print", str(out)], capture_output=True, text=True, timeout=120).stdout
    for o in scene.obstacles:
        assert re.search(rf"/scene/obstacles/{o.name} - data columns: \[Mesh3D", printed), f"no mesh for {o.name}"
    assert re.search(r"/scene/target/target - data columns: \[Mesh3D", printed), "no target mesh"
    for a in "xyz":
        assert re.search(rf"/sdf/slice_{a}/image - data columns: \[Mesh3D:albedo_texture", printed), f"no {a} slice"
        assert re.search(rf"/sdf/slice_{a}/zero_level - data columns: \[LineStrips3D", printed), f"no {a} contour"
    assert re.search(r"/sdf/anchors - data columns: \[Points3D", printed), "no anchor points"


@pytest.mark.parametrize("args, messages", [
    (["show", "scene=nope"], ["Could not find 'scene/nope'", "Available options in 'scene'", "tabletop"]),
    (["show", "n_e=1"], ["n_e (anchors per axis) must be an integer in [2, 256], got 1"]),
    (["draw"], ["usage: python -m samp.scene show"]),
])
def test_show_rejects_bad_arguments(args, messages):
    proc = _run(*args)
    assert proc.returncode == 2, f"exit code 2 expected, got {proc.returncode}: {proc.stderr}"
    for message in messages:
        assert message in proc.stderr, proc.stderr
    assert "Traceback" not in proc.stderr
