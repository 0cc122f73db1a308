"""Perception refuses nonsense instead of reconstructing an empty world (issue 21): no points, only
non-finite points, a cloud in millimetres or in another frame are errors; dropped points are warnings
with their share; the grid from a partly-NaN cloud is the grid of its finite points."""

from __future__ import annotations

import warnings

import numpy as np
import pytest

from samp.perception import Scan, load_point_cloud, reconstruct_grid
from samp.sim import World
from samp.sim.camera import robot_volume

N_E = 16


@pytest.fixture(scope="module")
def hits(panda, box_scene, ring_cameras):
    """The measured surface points of the box scene, every camera together: (N, 3) metres."""
    q = panda.home.numpy().copy()
    q[0] = 2.6
    with World(panda, box_scene) as world:
        scans = world.capture(ring_cameras(), q=q)
    return np.concatenate([s.hits for s in scans])


def _grid(points, bounds, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return reconstruct_grid([Scan(points)], N_E, bounds, **kw).grid


def test_no_points_is_an_error(box_scene, tmp_path):
    with pytest.raises(ValueError, match="hold no points: .* empty world"):
        reconstruct_grid([Scan(np.zeros((0, 3)))], N_E, box_scene.bounds)
    np.save(tmp_path / "empty.npy", np.zeros((0, 3)))
    with pytest.raises(ValueError, match="empty.npy holds no points"):
        load_point_cloud(tmp_path / "empty.npy")


def test_all_nan_is_an_error(box_scene, tmp_path):
    with pytest.raises(ValueError, match="points must be finite"):
        reconstruct_grid([Scan(np.full((50, 3), np.nan))], N_E, box_scene.bounds)
    np.save(tmp_path / "nan.npy", np.full((50, 3), np.nan))
    with pytest.raises(ValueError, match="nan.npy: all 50 points are NaN or infinite"):
        load_point_cloud(tmp_path / "nan.npy")


def test_some_nan_points_are_dropped_with_their_share(hits, box_scene, tmp_path):
    from samp.perception import scan_from_file

    cloud = hits.copy()
    cloud[::4] = np.nan  # a quarter of the points
    bad = len(cloud[::4])
    np.save(tmp_path / "some.npy", cloud)
    with pytest.warns(UserWarning, match=rf"some.npy: {bad} of {len(cloud)} points \(25\.0%\) are NaN or infinite"):
        scan = scan_from_file(tmp_path / "some.npy")
    finite = cloud[np.isfinite(cloud).all(axis=1)]
    np.testing.assert_array_equal(scan.hits, finite)
    assert bool((_grid(scan.hits, box_scene.bounds) == _grid(finite, box_scene.bounds)).all())


def test_millimetres_are_refused_with_the_unit_hint(hits, box_scene):
    with pytest.raises(ValueError, match=r"only \d+ of \d+ points \(\d+\.\d%\) lie inside the workspace.*"
                                         r"if it is in millimetres, scale it by 0\.001"):
        reconstruct_grid([Scan(hits * 1000.0)], N_E, box_scene.bounds)


def test_a_cloud_in_another_frame_is_refused(hits, box_scene):
    """Shifted 1 m down, no point is left inside the workspace: the grid would read 'no obstacles'."""
    with pytest.raises(ValueError, match=r"only 0 of \d+ points .* lie inside the workspace: the points span .*"
                                         r"another frame .*transform=T"):
        reconstruct_grid([Scan(hits - [0.0, 0.0, 1.0])], N_E, box_scene.bounds)


def test_a_shifted_cloud_that_mostly_misses_the_workspace_warns_with_the_share(hits, box_scene):
    shifted = hits + [1.0, 0.0, 0.0]
    _, inside = __import__("samp.perception.reconstruct", fromlist=["Lattice"]).Lattice.make(
        N_E, box_scene.bounds, 0.1).index(shifted)
    outside = int((~inside).sum())
    assert outside > 0.5 * len(shifted)  # the oracle: most points fall outside bounds + padding
    with pytest.warns(UserWarning, match=rf"{outside} of {len(shifted)} points \(\d+\.\d%\) lie outside the workspace"):
        reconstruct_grid([Scan(shifted)], N_E, box_scene.bounds)


def test_points_on_the_robot_s_own_volume_warn(panda, box_scene):
    """Points where the robot stands (known free at capture time) mean the cloud is in another frame."""
    q = panda.home.numpy()
    on_robot = panda.transform_points(panda.home[None])[0].numpy()  # robot points, on shells around its links
    bounds = ((-0.5, -0.5, 0.05), (0.8, 0.5, 1.2))
    free = robot_volume(panda, q, 0.07)
    assert free(on_robot).mean() > 0.5  # the oracle: these points lie in the robot's volume
    with pytest.warns(UserWarning, match="lie on the robot's own volume"):
        reconstruct_grid([Scan(on_robot)], N_E, bounds, known_free=free)
