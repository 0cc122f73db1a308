"""Cloud files that lie about their size: a header's count is checked against the bytes present and
against `MAX_POINTS` before anything is allocated, and a header declaring fewer points than the file holds
is refused, not read as its first rows."""

from __future__ import annotations

import numpy as np
import pytest

from samp.perception import load_point_cloud, save_point_cloud
from samp.perception.cloud import MAX_POINTS

XYZ = b"property float x\nproperty float y\nproperty float z\n"


def _ply(fmt: str, count: int, body: bytes, more: bytes = b"") -> bytes:
    return b"ply\nformat " + fmt.encode() + b" 1.0\nelement vertex " + str(count).encode() + b"\n" + XYZ + more \
        + b"end_header\n" + body


def test_ascii_ply_claiming_two_billion_vertices_is_refused_before_reading(tmp_path):
    """The fault: 713 bytes claiming 2,000,000,000 vertices grew memory until the OOM killer acted."""
    path = tmp_path / "bomb.ply"
    path.write_bytes(_ply("ascii", 2_000_000_000, b"0 0 0\n" * 100))
    data = 600  # the bytes after the header
    with pytest.raises(ValueError, match=rf"bomb.ply: the header declares 2000000000 rows of PLY element 'vertex', "
                                         rf"the file's {data} bytes of data hold at most {data // 6}"):
        load_point_cloud(path)


@pytest.mark.parametrize("fmt", ["binary_little_endian", "binary_big_endian"])
def test_binary_ply_with_a_huge_count_is_refused(tmp_path, fmt):
    path = tmp_path / "bomb.ply"
    path.write_bytes(_ply(fmt, 10**18, bytes(120)))
    with pytest.raises(ValueError, match=r"declares 1000000000000000000 rows .*\(12 bytes each\), the file's 120 bytes "
                                         r"of data hold at most 10"):
        load_point_cloud(path)


def test_a_count_the_file_holds_but_above_the_limit_is_refused(tmp_path, monkeypatch):
    import samp.perception.cloud as cloud

    monkeypatch.setattr(cloud, "MAX_POINTS", 5)
    save_point_cloud(tmp_path / "six.ply", np.zeros((6, 3)))
    with pytest.raises(ValueError, match="declares 6 rows .* more than the 5 a cloud file may hold; downsample"):
        load_point_cloud(tmp_path / "six.ply")
    assert MAX_POINTS >= 10_000_000  # real sensor clouds (a few million points) stay readable


@pytest.mark.parametrize("fmt", ["ascii", "binary"])
def test_ply_header_claiming_fewer_vertices_than_the_file_holds_is_refused(tmp_path, fmt):
    """The fault: the rest of the vertices were dropped silently."""
    points = np.arange(15, dtype=np.float64).reshape(5, 3)
    if fmt == "ascii":
        content = _ply("ascii", 3, b"".join(b"%g %g %g\n" % tuple(p) for p in points))
        extra = "2 lines"
    else:
        content = _ply("binary_little_endian", 3, points.astype("<f4").tobytes())
        extra = "24 bytes"
    (tmp_path / "short.ply").write_bytes(content)
    with pytest.raises(ValueError, match=rf"declares 3 vertices, but {extra} of data follow them that no element"):
        load_point_cloud(tmp_path / "short.ply")


def test_ply_with_faces_after_the_vertices_still_reads(tmp_path):
    """Data after the vertices that the header declares (a face element) is not an excess."""
    faces = b"element face 1\nproperty list uchar int vertex_indices\n"
    content = _ply("ascii", 3, b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", more=faces)
    (tmp_path / "mesh.ply").write_bytes(content)
    assert load_point_cloud(tmp_path / "mesh.ply").shape == (3, 3)
    (tmp_path / "extra.ply").write_bytes(content + b"3 0 1 2\n")
    with pytest.raises(ValueError, match="1 lines of data follow them"):
        load_point_cloud(tmp_path / "extra.ply")


PCD = b"VERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nPOINTS %d\nDATA %s\n"


@pytest.mark.parametrize("data, body, message", [
    (b"binary", bytes(36), r"declares 99999999999999999999 PCD points, the file's 36 bytes of data hold at most 3"),
    (b"ascii", b"1 2 3\n" * 3, r"declares 99999999999999999999 PCD points, the file's 18 bytes of data hold at most 3"),
])
def test_pcd_with_a_huge_count_is_refused(tmp_path, data, body, message):
    (tmp_path / "bomb.pcd").write_bytes(PCD % (99999999999999999999, data) + body)
    with pytest.raises(ValueError, match=message):
        load_point_cloud(tmp_path / "bomb.pcd")


@pytest.mark.parametrize("data, body, message", [
    (b"binary", bytes(36), "says 2 points, but 12 bytes of data follow them"),
    (b"ascii", b"1 2 3\n" * 3, "says 2 points, the file holds 3"),
])
def test_pcd_claiming_fewer_points_than_it_holds_is_refused(tmp_path, data, body, message):
    (tmp_path / "short.pcd").write_bytes(PCD % (2, data) + body)
    with pytest.raises(ValueError, match=message):
        load_point_cloud(tmp_path / "short.pcd")


def test_npy_whose_header_claims_a_huge_shape_is_refused(tmp_path):
    """The fault: a MemoryError/OverflowError traceback. Its header claims (10**12, 3) over 12 values."""
    from numpy.lib import format as npy

    path = tmp_path / "bomb.npy"

    with open(path, "wb") as f:
        npy.write_array_header_1_0(f, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 3)})
        f.write(np.zeros((4, 3)).tobytes())
    with pytest.raises(ValueError, match=r"bomb.npy: the header declares 3000000000000 values of float64 "
                                         r"\(shape \(1000000000000, 3\)\), the file's 96 bytes of data hold at most 12"):
        load_point_cloud(path)


def test_npy_within_its_bytes_still_loads(tmp_path):
    np.save(tmp_path / "ok.npy", np.ones((4, 3)))
    assert load_point_cloud(tmp_path / "ok.npy").shape == (4, 3)
