"""Point cloud files: PLY (ascii, binary both byte orders), PCD (ascii, binary) and NPY round trips, files
written by other tools, and clear errors."""

from __future__ import annotations

import numpy as np
import pytest

from samp.perception import Scan, load_point_cloud, save_point_cloud, scan_from_file

POINTS = np.random.default_rng(0).uniform(-1, 1, size=(50, 3))


@pytest.mark.parametrize("name, ascii", [("c.ply", False), ("c.ply", True), ("c.pcd", False), ("c.pcd", True),
                                         ("c.npy", False)])
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
     b"property float z\nend_header\n" + b"\x00" * 40, "declares 10 rows .*, the file's 40 bytes of data hold at most 3: it is cut short"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n1 2 3\n",
     "declares 3 rows of PLY element 'vertex', the file's 6 bytes of data hold at most 1"),
    (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\nend_header\n"
     b"1 2 3\n4 5\n6 7 8 9\n", "expects 3 rows of 3 values"),
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
    (tmp_path / "c.xyz").write_text("x")
    with pytest.raises(ValueError, match="unknown point cloud format '.xyz'; expected .ply, .pcd or .npy"):
        load_point_cloud(tmp_path / "c.xyz")
    with pytest.raises(FileNotFoundError, match="does not exist"):
        load_point_cloud(tmp_path / "missing.ply")
    with pytest.raises(ValueError, match="must be an \\(N, 3\\) array"):
        save_point_cloud(tmp_path / "x.ply", np.zeros((3, 2)))
    with pytest.raises(ValueError, match="must be finite"):
        Scan(np.full((2, 3), np.nan))
    with pytest.raises(ValueError, match="free_ends need the sensor origin"):
        Scan(np.zeros((2, 3)), free_ends=np.ones((2, 3)))


def test_pcd_as_the_point_cloud_library_writes_it(tmp_path):
    """A binary PCD with an extra field before x (as PCL writes an XYZI or XYZRGB cloud: fields side by
    side per point), and an ascii one with a multi-count field: x, y, z come out, the rest is skipped."""
    table = np.zeros(len(POINTS), dtype=[("intensity", "<f4"), ("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("ring", "<u2")])
    table["x"], table["y"], table["z"], table["intensity"], table["ring"] = *POINTS.T, 7.0, 3
    header = ("# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS intensity x y z ring\nSIZE 4 4 4 4 2\n"
              f"TYPE F F F F U\nCOUNT 1 1 1 1 1\nWIDTH {len(POINTS)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
              f"POINTS {len(POINTS)}\nDATA binary\n")
    (tmp_path / "b.pcd").write_bytes(header.encode() + table.tobytes())
    np.testing.assert_allclose(load_point_cloud(tmp_path / "b.pcd"), POINTS.astype("<f4"), atol=0, rtol=0)
    rows = "\n".join(f"{x} {y} {z} 1 2 3" for x, y, z in POINTS[:3])
    text = ("VERSION .7\nFIELDS x y z normal\nSIZE 8 8 8 4\nTYPE F F F F\nCOUNT 1 1 1 3\nWIDTH 3\nHEIGHT 1\n"
            f"POINTS 3\nDATA ascii\n{rows}\n")
    (tmp_path / "a.pcd").write_text(text)
    np.testing.assert_allclose(load_point_cloud(tmp_path / "a.pcd"), POINTS[:3], atol=1e-12, rtol=0)


@pytest.mark.parametrize("content, message", [
    (b"VERSION 0.7\nFIELDS x y\nSIZE 4 4\nTYPE F F\nCOUNT 1 1\nPOINTS 1\nDATA ascii\n1 2\n", "x, y and z are needed"),
    (b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 10\nDATA binary\n" + bytes(12), "cut short"),
    (b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nPOINTS 1\nDATA binary_compressed\n", "convert it"),
    (b"VERSION 0.7\nFIELDS x y z\n", "lacks"),
])
def test_bad_pcd_files_say_what_is_wrong(tmp_path, content, message):
    (tmp_path / "bad.pcd").write_bytes(content)
    with pytest.raises(ValueError, match=message):
        load_point_cloud(tmp_path / "bad.pcd")
