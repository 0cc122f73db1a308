"""Point clouds: reading and writing clouds as PLY, PCD or NPY files, and a `Scan` from a user's cloud file.

`Scan` and `DepthView`, what a depth camera produces, live in the sim layer (`samp.sim.scan`, beside the
camera that makes them) and are re-exported here: a `Scan` is the sensor position and, in the robot base
frame, the surface points it measured and the ends of rays seen free.

Files hold points only.
- PLY: ascii, binary_little_endian or binary_big_endian, a `vertex` element with float or double `x`, `y`,
  `z` properties (other properties and elements are skipped; list properties are allowed after the vertex
  element only). Written by trimesh; read here rather than by trimesh, which accepts a file cut short (a
  header announcing 3 vertices over 1 row of data loads as 1 point) and answers other damage with an
  IndexError or KeyError, where a user needs to be told what is wrong.
- PCD (the Point Cloud Library's format, v0.7): DATA ascii or binary, x, y, z among its fields (others
  are skipped).
- NPY: a float array (N, 3), or (..., 3) such as an organised (H, W, 3) cloud.
Non-finite points (a sensor's invalid pixels) are dropped on reading.

Counts in a header are checked against the bytes the file holds before anything is allocated (a header
claiming two billion vertices over a few bytes is refused, not read line by line until memory runs out),
against `MAX_POINTS`, and, where the format allows, against the data that follows: a PLY or PCD header
declaring fewer points than the file holds is refused rather than read as its first rows.
"""

from __future__ import annotations

import os
import warnings
from pathlib import Path

import numpy as np

from samp.sim.scan import DepthView, Scan, as_points

__all__ = ["DepthView", "Scan", "load_point_cloud", "save_point_cloud", "scan_from_file"]

PLY_TYPES = {"char": "i1", "int8": "i1", "uchar": "u1", "uint8": "u1", "short": "i2", "int16": "i2",
             "ushort": "u2", "uint16": "u2", "int": "i4", "int32": "i4", "uint": "u4", "uint32": "u4",
             "float": "f4", "float32": "f4", "double": "f8", "float64": "f8"}
PLY_FORMATS = {"ascii": None, "binary_little_endian": "<", "binary_big_endian": ">"}
MAX_POINTS = 50_000_000  # the most points (rows of a PLY element) a cloud file may declare: ~1.2 GB as float64


def _check_count(path: Path, what: str, declared: int, data_bytes: int, row_bytes: int) -> None:
    """Refuse a declared count of rows (each at least `row_bytes` long) that the `data_bytes` left in the file
    cannot hold, or one above `MAX_POINTS`, before anything of that size is allocated."""
    possible = data_bytes // max(row_bytes, 1)
    if declared < 0:
        raise ValueError(f"{path}: the header declares {declared} {what}; a count cannot be negative")
    if declared > possible:
        raise ValueError(f"{path}: the header declares {declared} {what}, the file's {data_bytes} bytes of data hold at "
                         f"most {possible}: it is cut short or its header is wrong")
    if declared > MAX_POINTS:
        raise ValueError(f"{path}: the header declares {declared} {what}, more than the {MAX_POINTS} a cloud file may "
                         "hold; downsample the cloud (e.g. a voxel filter) before reading it")


def _left(f) -> int:
    """Bytes left in the open file `f` after its current position."""
    return os.fstat(f.fileno()).st_size - f.tell()


# ----------------------------------------------------------------------------------------------- reading
def _ply_header(f, path: Path) -> tuple[str, list[tuple[str, int, list]]]:
    """Parse a PLY header: (format, [(element, count, [(property, dtype or ('list', count, item))])])."""
    if f.readline().strip() != b"ply":
        raise ValueError(f"{path} is not a PLY file: it does not start with the line 'ply'")
    fmt, elements = None, []
    for raw in iter(f.readline, b""):
        words = raw.decode("ascii", errors="replace").split()
        if not words or words[0] in ("comment", "obj_info"):
            continue
        if words[0] == "end_header":
            if fmt is None:
                raise ValueError(f"{path}: the PLY header has no 'format' line")
            return fmt, elements
        if words[0] == "format":
            if len(words) < 2 or words[1] not in PLY_FORMATS:
                raise ValueError(f"{path}: unknown PLY format {' '.join(words[1:])!r}; expected one of {list(PLY_FORMATS)}")
            fmt = words[1]
        elif words[0] == "element" and len(words) == 3 and words[2].isdigit():
            elements.append((words[1], int(words[2]), []))
        elif words[0] == "property" and elements:
            if words[1] == "list" and len(words) == 5 and words[2] in PLY_TYPES and words[3] in PLY_TYPES:
                elements[-1][2].append((words[4], ("list", PLY_TYPES[words[2]], PLY_TYPES[words[3]])))
            elif len(words) == 3 and words[1] in PLY_TYPES:
                elements[-1][2].append((words[2], PLY_TYPES[words[1]]))
            else:
                raise ValueError(f"{path}: cannot read the PLY header line {raw.decode(errors='replace').strip()!r}")
        else:
            raise ValueError(f"{path}: cannot read the PLY header line {raw.decode(errors='replace').strip()!r}")
    raise ValueError(f"{path}: the PLY header never ends (no 'end_header' line); the file is cut short or not PLY")


def _ply_vertices(f, path: Path, fmt: str, elements) -> np.ndarray:
    """The (N, 3) x, y, z of the vertex element; elements before it must have fixed-size rows."""
    for name, count, props in elements:
        if any(isinstance(t, tuple) for _, t in props):
            raise ValueError(f"{path}: PLY element {name!r} before the vertices has list properties; "
                             "put the vertex element first")
        names = [p for p, _ in props]
        if fmt == "ascii":  # each value takes at least a digit and a separator
            _check_count(path, f"rows of PLY element {name!r}", count, _left(f), 2 * len(props))
            rows = [f.readline().split() for _ in range(count)]
            if any(len(r) != len(props) for r in rows):
                raise ValueError(f"{path}: PLY element {name!r} expects {count} rows of {len(props)} values; the "
                                 "data is cut short or malformed")
            data = np.array(rows, dtype=np.float64).reshape(count, len(props))
            columns = {p: data[:, i] for i, p in enumerate(names)}
        else:
            dtype = np.dtype([(p, PLY_FORMATS[fmt] + t) for p, t in props])
            _check_count(path, f"rows of PLY element {name!r} ({dtype.itemsize} bytes each)", count, _left(f),
                         dtype.itemsize)
            buf = f.read(dtype.itemsize * count)
            if len(buf) != dtype.itemsize * count:
                raise ValueError(f"{path}: PLY element {name!r} needs {dtype.itemsize * count} bytes of data, the "
                                 f"file has {len(buf)}: it is cut short")
            data = np.frombuffer(buf, dtype=dtype)
            columns = {p: data[p] for p in names}
        if name == "vertex":
            missing = [a for a in "xyz" if a not in columns]
            if missing:
                raise ValueError(f"{path}: the PLY vertex element has properties {names}, missing {missing}")
            _ply_rest(f, path, fmt, elements[[e[0] for e in elements].index("vertex") + 1:], count)
            return np.stack([columns[a].astype(np.float64) for a in "xyz"], axis=1)
    raise ValueError(f"{path}: the PLY file has no 'vertex' element (elements: {[e[0] for e in elements]})")


def _ply_rest(f, path: Path, fmt: str, later, vertices: int) -> None:
    """Refuse data after the vertices that the header does not declare (a header claiming fewer vertices than
    the file holds): ascii, the lines left must be the rows of the later elements; binary, the bytes left
    must be theirs when their rows have a fixed size (with list properties, their size is not checked)."""
    if fmt == "ascii":
        extra = sum(1 for line in f if line.strip()) - sum(count for _, count, _ in later)
        unit = "lines"
    elif any(isinstance(t, tuple) for _, _, props in later for _, t in props):
        return
    else:
        sizes = [np.dtype([(p, PLY_FORMATS[fmt] + t) for p, t in props]).itemsize for _, _, props in later]
        extra = _left(f) - sum(size * count for size, (_, count, _) in zip(sizes, later))
        unit = "bytes"
    if extra > 0:
        raise ValueError(f"{path}: the header declares {vertices} vertices, but {extra} {unit} of data follow them "
                         "that no element of the header accounts for; the header's vertex count is wrong")


def load_point_cloud(path: str | Path) -> np.ndarray:
    """Read a `.ply`, `.pcd` or `.npy` point cloud -> (N, 3) float64, non-finite points dropped (with a warning
    giving their share: invalid pixels of an organised cloud are normal, a mostly-NaN cloud is not).

    Raises FileNotFoundError for a missing file and ValueError (saying what was wrong) for a bad one, one
    without points, or one whose points are all NaN or infinite.
    """
    path = Path(path).expanduser()
    if not path.is_file():
        raise FileNotFoundError(f"point cloud file {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".ply":
        with open(path, "rb") as f:
            fmt, elements = _ply_header(f, path)
            points = _ply_vertices(f, path, fmt, elements)
    elif suffix == ".pcd":
        with open(path, "rb") as f:
            points = _pcd_points(f, path)
    elif suffix == ".npy":
        _check_npy(path)
        try:
            arr = np.load(path, allow_pickle=False)
        except ValueError as err:
            raise ValueError(f"{path} is not a readable NPY array ({err}); save points with numpy.save") from None
        if arr.dtype.kind not in "fiu" or arr.ndim < 2 or arr.shape[-1] != 3:
            raise ValueError(f"{path}: expected a numeric (N, 3) or (..., 3) array of x, y, z, got dtype {arr.dtype} "
                             f"and shape {arr.shape}")
        points = arr.reshape(-1, 3).astype(np.float64)
    else:
        raise ValueError(f"{path}: unknown point cloud format {path.suffix!r}; expected .ply, .pcd or .npy")
    if len(points) == 0:
        raise ValueError(f"{path} holds no points: a reconstruction from it would be an empty world")
    finite = np.isfinite(points).all(axis=1)
    if not finite.any():
        raise ValueError(f"{path}: all {len(points)} points are NaN or infinite; the cloud holds no measurement")
    if not finite.all():

        bad = int((~finite).sum())
        warnings.warn(f"{path}: {bad} of {len(points)} points ({bad / len(points):.1%}) are NaN or infinite and are "
                      "dropped", stacklevel=2)
    return points[finite]


def _check_npy(path: Path) -> None:
    """Refuse an NPY file whose header's shape needs more (or fewer) bytes than the file holds, or more than
    `MAX_POINTS` points, before numpy allocates the array; the header itself is read by numpy's own reader."""
    from numpy.lib import format as npy

    with open(path, "rb") as f:
        try:
            version = npy.read_magic(f)
            read = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
            shape, _, dtype = read(f)
        except (ValueError, OSError, SyntaxError) as err:
            raise ValueError(f"{path} is not a readable NPY array ({err}); save points with numpy.save") from None
        count = int(np.prod(shape, dtype=object)) if shape else 1
        if dtype.hasobject or dtype.itemsize == 0:
            return  # refused by the dtype check after loading (np.load without pickles reads nothing of it)
        _check_count(path, f"values of {dtype} (shape {shape})", count, _left(f), dtype.itemsize)
        if count // 3 > MAX_POINTS:
            _check_count(path, "points", count // 3, count // 3 * 3 * dtype.itemsize, 3 * dtype.itemsize)


def save_point_cloud(path: str | Path, points, ascii: bool = False) -> Path:
    """Write (N, 3) points as `.ply` or `.pcd` (binary little-endian float32, or ascii) or `.npy` (float64)."""
    path, points = Path(path), as_points(points, "points")
    path.parent.mkdir(parents=True, exist_ok=True)
    if path.suffix.lower() == ".npy":
        np.save(path, points)
    elif path.suffix.lower() == ".ply":  # trimesh's writer: a float32 x, y, z vertex element
        import trimesh

        path.write_bytes(trimesh.PointCloud(points).export(file_type="ply", encoding="ascii" if ascii else "binary"))
    elif path.suffix.lower() == ".pcd":
        header = (f"# .PCD v0.7 - samp point cloud, robot base frame, metres\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\n"
                  f"TYPE F F F\nCOUNT 1 1 1\nWIDTH {len(points)}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\n"
                  f"POINTS {len(points)}\nDATA {'ascii' if ascii else 'binary'}\n")
        with open(path, "wb") as f:
            f.write(header.encode("ascii"))
            if ascii:
                np.savetxt(f, points, fmt="%.7g")
            else:
                f.write(points.astype("<f4").tobytes())
    else:
        raise ValueError(f"{path}: unknown point cloud format {path.suffix!r}; expected .ply, .pcd or .npy")
    return path


PCD_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
             ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}


def _pcd_points(f, path: Path) -> np.ndarray:
    """The x, y, z fields of a PCD file (point cloud library format, v0.7): DATA ascii or binary
    (little-endian, point after point); binary_compressed is refused with what to do."""
    fields: dict[str, list[str]] = {}
    for _ in range(64):  # the header is a handful of lines
        raw = f.readline()
        if not raw:
            break
        line = raw.decode("ascii", errors="replace").strip()
        if not line or line.startswith("#"):
            continue
        key, *values = line.split()
        fields[key.upper()] = values
        if key.upper() == "DATA":
            break
    else:
        raise ValueError(f"{path}: the PCD header has no DATA line within 64 lines; the file is not PCD")
    missing = [k for k in ("FIELDS", "SIZE", "TYPE", "POINTS", "DATA") if k not in fields]
    if missing:
        raise ValueError(f"{path}: the PCD header lacks {missing}; the file is cut short or not PCD")
    names, sizes, types = fields["FIELDS"], [int(v) for v in fields["SIZE"]], fields["TYPE"]
    counts = [int(v) for v in fields.get("COUNT", ["1"] * len(names))]
    if not {"x", "y", "z"} <= set(names):
        raise ValueError(f"{path}: the PCD fields are {names}; x, y and z are needed")
    if not len(names) == len(sizes) == len(types) == len(counts):
        raise ValueError(f"{path}: the PCD header's FIELDS, SIZE, TYPE and COUNT lines differ in length")
    try:
        dtype = np.dtype([(n, "<" + PCD_TYPES[(t, s)]) if c == 1 else (n, "<" + PCD_TYPES[(t, s)], (c,))
                          for n, s, t, c in zip(names, sizes, types, counts)])
    except KeyError as err:
        raise ValueError(f"{path}: unknown PCD field type/size {err.args[0]}") from None
    n, data = int(fields["POINTS"][0]), fields["DATA"][0].lower()
    if data in ("ascii", "binary"):
        _check_count(path, "PCD points", n, _left(f), 2 * sum(counts) if data == "ascii" else dtype.itemsize)
    if data == "ascii":
        lines = [line for line in f if line.strip()]  # bounded: n fits in the file's bytes
        if len(lines) != n:
            raise ValueError(f"{path}: the PCD header says {n} points, the file holds {len(lines)}")
        rows = np.loadtxt(lines, dtype=np.float64, ndmin=2) if n else np.zeros((0, sum(counts)))
        column = {name: int(np.sum(counts[:i])) for i, name in enumerate(names)}
        return rows[:, [column["x"], column["y"], column["z"]]]
    if data == "binary":
        raw = f.read(dtype.itemsize * n)
        if len(raw) != dtype.itemsize * n:
            raise ValueError(f"{path}: the PCD header says {n} points ({dtype.itemsize * n} bytes), the file holds "
                             f"{len(raw)} bytes of data; it is cut short")
        if _left(f):
            raise ValueError(f"{path}: the PCD header says {n} points, but {_left(f)} bytes of data follow them; the "
                             "header's point count is wrong")
        table = np.frombuffer(raw, dtype=dtype)
        return np.stack([table["x"], table["y"], table["z"]], axis=1).astype(np.float64)
    raise ValueError(f"{path}: PCD DATA {data!r} is not read here (ascii or binary are); convert it, e.g. with "
                     "Open3D or pcl_convert_pcd_ascii_binary")


def scan_from_file(path: str | Path, origin=None, transform=None, name: str | None = None) -> Scan:
    """A `Scan` from a cloud file: points in the sensor frame moved into the base frame by `transform`
    (4, 4) sensor -> base (default: the points are already in the base frame). `origin` (3,) is the
    sensor position in the base frame (default: the transform's translation, or unknown)."""
    points = load_point_cloud(path)
    if transform is not None:
        T = np.asarray(transform, dtype=np.float64)
        if T.shape != (4, 4) or not np.allclose(T[3], [0, 0, 0, 1]):
            raise ValueError(f"transform must be a (4, 4) homogeneous sensor -> base transform, got {T.tolist()}")
        points = points @ T[:3, :3].T + T[:3, 3]
        origin = T[:3, 3] if origin is None else origin
    return Scan(points, origin=origin, name=name or Path(path).stem)
