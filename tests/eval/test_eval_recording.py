"""Rerun recordings of an evaluation: written, readable by the Rerun CLI, with the expected content."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from samp.eval import StraightLinePolicy, evaluate, load_planner, write_recording
from samp.viz.rollout import risk_colors

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`


def _rerun() -> str:
    exe = Path(sys.executable).with_name("rerun")
    found = str(exe) if exe.is_file() else shutil.which("rerun")
    if found is None:
        pytest.skip("the rerun CLI (rerun-sdk) is not on PATH next to this Python")
    return found


@pytest.fixture(scope="module")
def recording(tiny_problems, panda, tmp_path_factory):
    ds, problems = tiny_problems
    result = evaluate(StraightLinePolicy(panda), problems)
    expert = evaluate(load_planner("expert"), problems)
    path = tmp_path_factory.mktemp("rec") / "recording.rrd"
    write_recording(path, problems, result, expert, robot=panda, slice_n_e=16, record_rollouts=2, record_points=64,
                    metrics_md="| a | b |")
    return path, result


def test_the_recording_verifies_with_the_rerun_cli(recording):
    path, _ = recording
    out = subprocess.run([_rerun(), "rrd", "verify", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, f"rerun rrd verify failed:\n{out.stdout}\n{out.stderr}"


def test_the_recording_holds_the_rollouts(recording):
    path, result = recording
    out = subprocess.run([_rerun(), "rrd", "print", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    for entity in ("/world/robot/links/panda_hand", "/world/robot/points", "/world/paths/planner", "/world/paths/expert",
                   "/world/markers/goal", "/world/markers/collision", "/world/scene/obstacles/table", "/world/sdf/image",
                   "/plots/closest_point_distance", "/summary/rollout", "/summary/metrics"):
        assert entity in out.stdout, f"{entity} missing from the recording"
    assert any(r["collision"] for r in result["records"]), "a collision marker needs a colliding rollout"
    assert path.stat().st_size < 5e6, f"6 rollouts, 2 animated, should stay small; got {path.stat().st_size / 1e6:.1f} MB"


def test_risk_colors_run_from_red_at_contact_to_green_when_clear():
    colors = risk_colors(np.array([-0.05, 0.0, 0.1, 0.5]), clear=0.1)
    assert colors.shape == (4, 3) and colors.dtype == np.uint8
    np.testing.assert_array_equal(colors[0], colors[1])  # inside counts as contact
    np.testing.assert_array_equal(colors[2], colors[3])  # beyond `clear` counts as clear
    assert colors[0][0] > colors[0][1] and colors[2][1] > colors[2][0], f"red then green, got {colors.tolist()}"


def _trimesh_sdf(scene, points: np.ndarray) -> np.ndarray:
    """An oracle independent of `scene.sdf`: the minimum over obstacles of trimesh's signed distance to each
    primitive's mesh (trimesh: positive inside, hence the minus)."""
    import trimesh

    from samp.scene import Box, Cylinder, Sphere

    out = np.full(len(points), np.inf)
    for o in scene.all_obstacles:
        if isinstance(o, Box):
            mesh = trimesh.creation.box(extents=o.size)
        elif isinstance(o, Cylinder):
            mesh = trimesh.creation.cylinder(radius=o.radius, height=o.height, sections=256)
        elif isinstance(o, Sphere):
            mesh = trimesh.creation.icosphere(subdivisions=5, radius=o.radius)
        else:
            raise AssertionError(f"the tiny scenes hold primitives only, got {type(o).__name__}")
        mesh.apply_transform(o.pose.matrix())
        out = np.minimum(out, -trimesh.proximity.signed_distance(mesh, points))
    return out


def test_the_drawn_sdf_plane_is_the_exact_sdf_there(tiny_problems):
    """The plane the recording draws (z index 5 of the anchors, as `samp.eval.recording` computes it) is the
    scene's anchor grid there and matches trimesh's distances to the obstacles' meshes (to 2 mm: the
    tessellation of round obstacles). Catches a plane at the wrong index or axis, or a wrong SDF."""
    from samp.scene import anchor_points

    scene = tiny_problems[1][0].scene
    grid = scene.anchor_grid(12).numpy()
    points = anchor_points(12, scene.bounds)[:, :, 5]  # (12, 12, 3), indexed (x, y)
    plane = np.asarray(scene.sdf(points))
    np.testing.assert_allclose(plane, np.take(grid, 5, axis=2), atol=1e-6)
    oracle = _trimesh_sdf(scene, points.reshape(-1, 3).numpy()).reshape(12, 12)
    np.testing.assert_allclose(plane, oracle, atol=2e-3)
    assert (oracle < 0).any() or np.ptp(oracle) > 0.05, "the plane should cross or pass near an obstacle"


def _store_ids(rerun: str, path: Path) -> set[tuple[str, str]]:
    """(application id, recording id) of every recording in an .rrd, as the Rerun CLI reads the file."""
    import re

    out = subprocess.run([rerun, "rrd", "print", str(path)], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    return set(re.findall(r'StoreId\(\s*Recording,\s*"([^"]+)",\s*"([^"]+)"', out.stdout))


def test_two_runs_recordings_are_two_recordings_in_a_z_up_world(tiny_problems, panda, tmp_path):
    """Recording ids come from where the evaluation is written, so `rerun A.rrd B.rrd` shows two recordings
    rather than merging them; the world is z up (ViewCoordinates RIGHT_HAND_Z_UP, static, on /world)."""
    ds, problems = tiny_problems
    problems = problems[:2]
    result = evaluate(StraightLinePolicy(panda), problems)
    paths = [tmp_path / run / "eval" / "recording.rrd" for run in ("run_a", "run_b")]
    for path in paths:
        write_recording(path, problems, result, robot=panda, slice_n_e=8, record_rollouts=1, record_points=16)
    rerun = _rerun()
    (a,), (b,) = (_store_ids(rerun, p) for p in paths)
    assert a[0] == b[0] == "samp_eval" and a[1] != b[1], (a, b)
    out = subprocess.run([rerun, "rrd", "print", "-vvv", str(paths[0])], capture_output=True, text=True, timeout=300)
    import re

    found = re.search(r"entity_path: /world\s+│", out.stdout)
    assert found, "no chunk on /world in the recording"
    world = out.stdout[found.start():][:6000]
    assert "ViewCoordinates:xyz" in world, world
    # Rerun's ViewDir codes: Up 1, Right 3, Forward 5; RIGHT_HAND_Z_UP is X right, Y forward, Z up
    assert "[[3, 5, 1]]" in world, world
    write_recording(paths[0], problems, result, robot=panda, slice_n_e=8, record_rollouts=0, record_points=16)
    assert _store_ids(rerun, paths[0]) == {a}, "writing the same run's recording again keeps its id"
