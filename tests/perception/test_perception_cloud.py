"""Point cloud files: PLY (ascii, binary both byte orders) and NPY round trips, and clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from samp.perception import Scan, load_point_cloud, save_point_cloud, scan_from_file

POINTS = np.random.default_rng(0).uniform(-1, 1, size=(50, 3))


@pytest.mark.parametrize("name, ascii", [("c.ply", False), ("c.ply", True), ("c.npy", False)])
def test_round_trip(tmp_path, name, ascii):
    path = save_point_cloud(tmp_path / name, POINTS, ascii=ascii)
    got = load_point_cloud(path)
    tol = 0 if name.endswith(".npy") else 1e-6  # PLY stores float32
    np.testing.assert_allclose(got, POINTS, atol=tol, rtol=0)


def test_big_endian_ply_with_extra_properties_and_faces(tmp_path):
    """Written by hand as another tool would: doubles, a colour, and a face list after the vertices."""
    rows = np.zeros(len(POINTS), dtype=[("x", ">f8"), ("y", ">f8"), ("z", ">f8"), ("red", "u1")])
    rows["x"], rows["y"], rows["z"], rows["red"] = POINTS[:, 0], POINTS[:, 1], POINTS[:, 2], 200
    header = (f"ply\nformat binary_big_endian 1.0\ncomment from a sensor\nelement vertex {len(POINTS)}\n"
              "property double x\nproperty double y\nproperty double z\nproperty uchar red\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n")
    path = tmp_path / "be.ply"
    path.write_bytes(header.encode() + rows.tobytes() + b"\x03" + np.array([0, 1, 2], ">i4").tobytes())
    np.testing.assert_array_equal(load_point_cloud(path), POINTS)


def test_organised_npy_drops_invalid_pixels(tmp_path):
    image = POINTS[:48].reshape(6, 8, 3).copy()
    image[0, 0] = np.nan
    np.save(tmp_path / "o.npy", image)
    got = load_point_cloud(tmp_path / "o.npy")
    assert got.shape == (47, 3)
    np.testing.assert_array_equal(got, POINTS[1:48])


def test_scan_from_file_moves_points_into_the_base_frame(tmp_path):
    T = np.eye(4)
    T[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    T[:3, 3] = [0.5, 0.0, 1.0]
    scan = scan_from_file(save_point_cloud(tmp_path / "s.npy", POINTS), transform=T)
    np.testing.assert_allclose(scan.hits, POINTS @ T[:3, :3].T + T[:3, 3])
    np.testing.assert_array_equal(scan.origin, [0.5, 0.0, 1.0])
    assert scan_from_file(tmp_path / "s.npy").origin is None


@pytest.mark.parametrize("content, message", [
    (b"not a ply\n", "does not start with the line 'ply'"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\n", "never ends"),
    (b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nend_header\n1 2\n3 4\n",
     "missing \\['z'\\]"),
    (b"ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\nend_header\n",
     "before the vertices has list properties"),
    (b"ply\nformat ascii 1.0\nelement edge 0\nproperty int a\nend_header\n", "no 'vertex' element"),
    (b"ply\nformat binary_little_endian 1.0\nelement vertex 10\nproperty float x\nproperty float y\n"
     b"property float z\nend_header\n" + b"\x00" * 40, "needs 120 bytes of data, the file has 40"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
     "expects 3 rows of 3 values"),
    (b"ply\nformat binary_middle_endian 1.0\nend_header\n", "unknown PLY format"),
])
def test_bad_ply_files_say_what_is_wrong(tmp_path, content, message):
    path = tmp_path / "bad.ply"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message):
        load_point_cloud(path)


def test_bad_npy_and_other_files_say_what_is_wrong(tmp_path):
    np.save(tmp_path / "flat.npy", np.zeros((5, 2)))
    with pytest.raises(ValueError, match="expected a numeric \\(N, 3\\).*shape \\(5, 2\\)"):
        load_point_cloud(tmp_path / "flat.npy")
    (tmp_path / "junk.npy").write_bytes(b"garbage")
    with pytest.raises(ValueError, match="not a readable NPY array"):
        load_point_cloud(tmp_path / "junk.npy")
    (tmp_path / "c.pcd").write_text("x")
    with pytest.raises(ValueError, match="unknown point cloud format '.pcd'; expected .ply or .npy"):
        load_point_cloud(tmp_path / "c.pcd")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(ValueError, match="must be an \\(N, 3\\) array"):
        save_point_cloud(tmp_path / "x.ply", np.zeros((3, 2)))
    with pytest.raises(ValueError, match="must be finite"):
        Scan(np.full((2, 3), np.nan))
    with pytest.raises(ValueError, match="free_ends need the sensor origin"):
        Scan(np.zeros((2, 3)), free_ends=np.ones((2, 3)))
