"""Reading demonstrations recorded elsewhere: `.npz`, HDF5 and LeRobot folders -> `Recorded` trajectories in
the robot's joint order (the keys are listed in `samp.data.importing` and docs/datasets.md).

A source is untrusted input (docs/integrity.md): every field's declared shape and dtype is checked, and its
size bounded in bytes, before anything is allocated for it; an `.npz` is read without pickle, an HDF5 file
only through datasets stored in the file itself (no external or virtual storage, no soft or external links).
Whatever is wrong is a `SourceError` (a ValueError) naming the file and the key."""

from __future__ import annotations

import math
import tokenize
import zipfile
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["MAX_ARRAY_BYTES", "MAX_SOURCE_BYTES", "MAX_SOURCE_EPISODES", "Recorded", "SourceError", "read_source"]

MAX_ARRAY_BYTES = 512 << 20  # one array of a source as held in memory (numbers as float64): larger is refused unread
MAX_SOURCE_BYTES = 1 << 30  # all the arrays of one source together (an .npz's members as stored, a LeRobot folder)
MAX_SOURCE_EPISODES = 100_000  # trajectories in one source: each becomes a record and a collision check

KEYS = ("joint_positions", "episode_ends", "scene", "scenes", "episode_scene", "timestamps", "joint_names")
# key -> (the ndims it may have, the dtype kinds it may have: numbers "fiu", text "US")
FIELDS = {"joint_positions": ((2, 3), "fiu"), "episode_ends": ((1,), "iu"), "scene": ((0, 1), "US"),
          "scenes": ((1,), "US"), "episode_scene": ((1,), "iu"), "timestamps": ((1, 2), "fiu"),
          "joint_names": ((1,), "US")}
_NUMBERS = {"f": "floats", "i": "integers", "u": "integers", "U": "text", "S": "text"}


class SourceError(ValueError):
    """An import source that cannot be read as it is: the message names the file, the key and what to do."""


@dataclass
class Recorded:
    """One trajectory as recorded: q (T, n) radians, in the robot's joint order, and where it came from."""

    q: np.ndarray
    scene: str
    source: str  # file#index, for the summary and the episode record
    timestamps: np.ndarray | None = None


def read_source(path: Path, robot, scene: str | None = None, key: str = "observation.state",
                columns: list[int] | None = None) -> list[Recorded]:
    """The trajectories of one source (file or LeRobot folder); `scene` overrides/replaces its scene keys."""
    path = Path(path)
    if path.is_dir():
        from samp.data.import_lerobot import read_lerobot

        return read_lerobot(path, robot, scene, key, columns)
    if not path.is_file():
        raise FileNotFoundError(f"import source {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        arrays, keys = _read_npz(path)
    elif suffix in (".h5", ".hdf5"):
        arrays, keys = _read_hdf5(path)
    else:
        raise SourceError(f"import source {path}: unknown format {suffix!r}; expected .npz, .h5/.hdf5 or a LeRobot "
                          "dataset folder")
    return _from_arrays(arrays, keys, path, robot, scene, columns)


def first_line(err: BaseException) -> str:
    """A library's message, cut to its first line: ours must stay one line."""
    text = str(err.args[0] if isinstance(err, KeyError) and err.args else err).strip().splitlines()
    return text[0][:200] if text else type(err).__name__


def check_field(where: str, key: str, shape: tuple, dtype: np.dtype, kind: str) -> int:
    """Refuse a field whose declared ndim or dtype is not what `key` holds, or whose size passes MAX_ARRAY_BYTES;
    -> the bytes it will take once read (numbers as float64)."""
    ndims, kinds = FIELDS[key]
    if kind not in kinds:
        want = "numbers" if "f" in kinds else "integers" if "i" in kinds else "text"
        raise SourceError(f"{where}: `{key}` holds {dtype} ({_NUMBERS.get(kind, 'neither numbers nor text')}), "
                          f"expected {want}; see docs/datasets.md, Importing demonstrations")
    if len(shape) not in ndims:
        raise SourceError(f"{where}: `{key}` has shape {tuple(shape)}, expected ndim {' or '.join(map(str, ndims))}; "
                          "see docs/datasets.md, Importing demonstrations")
    if dtype.itemsize == 0:
        raise SourceError(f"{where}: `{key}` holds {dtype}, a type of zero bytes; expected numbers or text")
    size = math.prod(int(s) for s in shape) * max(dtype.itemsize, 8 if kind in "fiu" else 1)
    if size > MAX_ARRAY_BYTES:
        raise SourceError(f"{where}: `{key}` declares shape {tuple(shape)} of {dtype}, {size} bytes, more than the "
                          f"{MAX_ARRAY_BYTES} an import reads per array (MAX_ARRAY_BYTES); split it into several files")
    return size


def _check_total(where: str, total: int) -> None:
    if total > MAX_SOURCE_BYTES:
        raise SourceError(f"{where}: its arrays declare {total} bytes, more than the {MAX_SOURCE_BYTES} an import "
                          "reads per source (MAX_SOURCE_BYTES); split it into several files")


# The ways zipfile and zlib report a damaged archive (a wrong compression method is NotImplementedError, an
# encrypted member RuntimeError, a truncated one EOFError).
_ZIP_ERRORS = (zipfile.BadZipFile, zipfile.LargeZipFile, zlib.error, EOFError, NotImplementedError, RuntimeError,
               OSError)


def _read_npz(path: Path) -> tuple[dict, list[str]]:
    """The known keys of an .npz, each member's .npy header checked before its data is read -> (arrays, all keys)."""
    where = str(path)
    try:
        with zipfile.ZipFile(path) as archive:
            members = {info.filename.removesuffix(".npy"): info for info in archive.infolist()}
            _check_total(where, sum(info.file_size for info in members.values()))
            return {k: _read_member(archive, members[k], where, k) for k in KEYS if k in members}, list(members)
    except SourceError:
        raise
    except _ZIP_ERRORS as err:
        raise SourceError(f"import source {path} is not a readable .npz (a zip archive): {first_line(err)}") from None


def _read_member(archive: zipfile.ZipFile, info: zipfile.ZipInfo, where: str, key: str) -> np.ndarray:
    """One .npy member: magic and header read through zipfile, checked (no pickles, the field's shape and dtype,
    MAX_ARRAY_BYTES, no more data declared than the member holds), and only then its data."""
    from numpy.lib import format as npy

    with archive.open(info) as fp:
        try:
            version = npy.read_magic(fp)
            if version not in ((1, 0), (2, 0)):
                raise ValueError(f"unknown .npy format version {version}")
            read = npy.read_array_header_1_0 if version == (1, 0) else npy.read_array_header_2_0
            shape, fortran, dtype = read(fp, max_header_size=10_000)
        # numpy's own checks of the magic and the header; it tokenizes and evaluates the header's text, which
        # reports a garbled one as TokenError, SyntaxError or, nested deeply, RecursionError
        except (ValueError, TypeError, SyntaxError, tokenize.TokenError, RecursionError) as err:
            raise SourceError(f"{where}: member `{info.filename}` is not a readable .npy array: {first_line(err)}"
                              ) from None
        if dtype.hasobject:
            raise SourceError(f"{where}: `{key}` is an object array ({dtype}), which only pickle reads; store "
                              "trajectories as joint_positions (N, n) with episode_ends, not as an object array")
        if any(s < 0 for s in shape):
            raise SourceError(f"{where}: `{key}` declares the impossible shape {shape}")
        check_field(where, key, shape, dtype, dtype.kind)
        nbytes, held = math.prod(shape) * dtype.itemsize, info.file_size - fp.tell()
        if nbytes > held:
            raise SourceError(f"{where}: `{key}` declares shape {shape} of {dtype} ({nbytes} bytes), but its member "
                              f"holds {held} bytes of data; the file is damaged or was cut short")
        data = fp.read(nbytes)
    if len(data) < nbytes:
        raise SourceError(f"{where}: `{key}` holds {len(data)} of the {nbytes} bytes its header declares; the file "
                          "was cut short")
    return np.frombuffer(data, dtype=dtype).reshape(shape, order="F" if fortran else "C")


def _read_hdf5(path: Path) -> tuple[dict, list[str]]:
    """The known keys of an HDF5 file: each a dataset stored in this file, its shape and dtype checked before
    it is read -> (arrays, all top-level keys)."""
    try:
        import h5py
    except ImportError:
        raise ImportError("reading HDF5 needs h5py: pip install 'samp[import]' (or h5py)") from None
    where = str(path)
    try:
        f = h5py.File(path, "r")
    except OSError as err:
        raise SourceError(f"import source {path} is not a readable HDF5 file: {first_line(err)}") from None
    try:
        with f:
            # a damaged name that is not UTF-8 comes back as bytes
            keys = [k if isinstance(k, str) else k.decode(errors="replace") for k in f.keys()]
            found = {k: _hdf5_dataset(f, k, where) for k in KEYS if k in keys}
            _check_total(where, sum(size for _, size in found.values()))
            return {k: _hdf5_read(d, where, k) for k, (d, _) in found.items()}, keys
    except SourceError:
        raise
    except (OSError, RuntimeError, KeyError) as err:  # h5py's reports of a damaged file's structure
        raise SourceError(f"import source {path} is a damaged HDF5 file: {first_line(err)}") from None


def _hdf5_dataset(f, key: str, where: str):
    """The dataset at `key` -> (it, its size in bytes), refusing links, groups and storage outside the file."""
    import h5py

    link = f.get(key, getlink=True)
    if isinstance(link, (h5py.SoftLink, h5py.ExternalLink)):
        target = f"{link.filename}:{link.path}" if isinstance(link, h5py.ExternalLink) else link.path
        raise SourceError(f"{where}: `{key}` is a link to {target!r}; an import reads only datasets stored in the "
                          "file itself: copy the data in (h5py `f[key] = f[target][()]`)")
    obj = f[key]
    if not isinstance(obj, h5py.Dataset):
        raise SourceError(f"{where}: `{key}` is an HDF5 {type(obj).__name__.lower()}, expected a dataset (an array); "
                          "see docs/datasets.md, Importing demonstrations")
    if obj.is_virtual or obj.external:
        how = "a virtual dataset (its data lives in other files)" if obj.is_virtual else \
            f"stored in external files {[e[0] for e in obj.external]!r}"
        raise SourceError(f"{where}: `{key}` is {how}; an import reads only data stored in the file itself: "
                          "write the array into the file")
    if obj.shape is None:
        raise SourceError(f"{where}: `{key}` is an empty HDF5 dataspace, expected an array")
    kind = "U" if h5py.check_string_dtype(obj.dtype) else obj.dtype.kind
    return obj, check_field(where, key, obj.shape, obj.dtype, kind)


def _hdf5_read(dset, where: str, key: str) -> np.ndarray:
    try:
        value = np.asarray(dset[()])
    except (OSError, RuntimeError) as err:  # a damaged chunk, a filter this h5py lacks
        raise SourceError(f"{where}: `{key}` cannot be read: {first_line(err)}") from None
    if value.dtype.kind in "OS":  # strings come back as bytes
        try:
            text = [v.decode() if isinstance(v, bytes) else str(v) for v in value.ravel()]
            return np.array(text).reshape(value.shape)
        except UnicodeDecodeError as err:
            raise SourceError(f"{where}: `{key}` holds text that is not UTF-8: {first_line(err)}") from None
    return value


def columns_for(names: list[str] | None, width: int, robot, columns: list[int] | None, where: str,
                names_key: str = "`joint_names`") -> list[int]:
    """Which source columns are the robot's joints, in the robot's order; `names` (one per column) say which."""
    n = robot.dof
    if columns is not None:
        if len(columns) != n or not all(0 <= c < width for c in columns):
            raise SourceError(f"{where}: columns={columns} must list {n} column indices below {width}")
        return list(columns)
    if names is not None:
        if len(names) != width or len(set(names)) != len(names):
            raise SourceError(f"{where}: {names_key} names {len(names)} joints {names}, but the joint positions "
                              f"have {width} columns; give one distinct name per column (or columns=i,j,...)")
        missing = [j for j in robot.joint_names if j not in names]
        if missing:
            raise SourceError(f"{where}: the source's joints {names} lack the robot's {missing}; give columns=i,j,... "
                              f"for the {n} joints {robot.joint_names}")
        return [names.index(j) for j in robot.joint_names]
    if width < n:
        raise SourceError(f"{where}: {width} columns, but robot {robot.name!r} has {n} joints")
    return list(range(n))


def _from_arrays(arrays: dict, keys: list[str], path: Path, robot, scene: str | None,
                 columns: list[int] | None) -> list[Recorded]:
    where = str(path)
    if "joint_positions" not in arrays:
        raise SourceError(f"{where}: no `joint_positions` array (keys: {sorted(keys)}); see docs/datasets.md")
    q = np.asarray(arrays["joint_positions"], dtype=np.float64)
    names = [str(s) for s in arrays["joint_names"]] if "joint_names" in arrays else None
    if q.ndim == 3:
        _count(where, "joint_positions", q.shape[0])
        episodes = list(q)
    elif "episode_ends" in arrays:
        ends = _episode_ends(arrays["episode_ends"], len(q), where)
        episodes = np.split(q, ends[:-1])
    else:
        raise SourceError(f"{where}: joint_positions must be (K, T, n), or (N, n) with episode_ends; got {q.shape}")
    cols = columns_for(names, q.shape[-1], robot, columns, where)
    stamps = arrays.get("timestamps")
    if stamps is not None:
        if stamps.shape != q.shape[:-1]:
            raise SourceError(f"{where}: `timestamps` has shape {stamps.shape}, expected {q.shape[:-1]}: one per row "
                              "of joint_positions")
        stamps = np.asarray(stamps, dtype=np.float64)
        stamps = list(stamps) if stamps.ndim == 2 else np.split(stamps, np.cumsum([len(e) for e in episodes])[:-1])
    scenes = _scene_refs(arrays, len(episodes), scene, where)
    return [Recorded(e[:, cols], scenes[k], f"{path.name}#{k}", None if stamps is None else stamps[k])
            for k, e in enumerate(episodes)]


def _count(where: str, key: str, count: int) -> None:
    if count > MAX_SOURCE_EPISODES:
        raise SourceError(f"{where}: `{key}` holds {count} trajectories, more than the {MAX_SOURCE_EPISODES} an import "
                          "reads per source (MAX_SOURCE_EPISODES); split it into several files")


def _episode_ends(ends: np.ndarray, rows: int, where: str) -> np.ndarray:
    """`episode_ends` checked in its own integer type (a uint64 or int64 beyond the rows never wraps) -> int64."""
    _count(where, "episode_ends", len(ends))
    if len(ends) == 0 or ends.min() < 1 or ends.max() > rows:
        raise SourceError(f"{where}: `episode_ends` must hold end rows in 1..{rows} (the row count of "
                          f"joint_positions), got {ends[:5].tolist()}")
    ends = ends.astype(np.int64)
    if np.any(np.diff(ends) <= 0) or ends[-1] != rows:
        raise SourceError(f"{where}: `episode_ends` must increase strictly and end at the row count {rows}, got "
                          f"{ends[:5].tolist()}...{ends[-1:].tolist()}")
    return ends


def check_scene_ref(ref: str, where: str, key: str) -> str:
    """A scene reference read from a source: one printable line of sensible length (it becomes a path)."""
    if not ref or len(ref) > 4096 or not ref.isprintable():
        raise SourceError(f"{where}: `{key}` holds {ref[:80]!r}, not a scene reference (a scene file or "
                          "GENERATOR:SEED)")
    return ref


def _scene_refs(arrays: dict, count: int, scene: str | None, where: str) -> list[str]:
    if scene is not None:
        return [scene] * count
    if "scene" in arrays:
        one = np.atleast_1d(arrays["scene"])
        if one.size != 1:
            raise SourceError(f"{where}: `scene` must hold one scene reference, holds {one.size}; for several use "
                              "`scenes` with `episode_scene`")
        return [check_scene_ref(str(one[0]), where, "scene")] * count
    if "scenes" in arrays and "episode_scene" in arrays:
        refs = [check_scene_ref(str(s), where, "scenes") for s in arrays["scenes"]]
        if not refs:
            raise SourceError(f"{where}: `scenes` is empty; it must list the scene references `episode_scene` indexes")
        index = arrays["episode_scene"]
        if len(index) != count or (count and (index.min() < 0 or index.max() >= len(refs))):
            raise SourceError(f"{where}: `episode_scene` must hold {count} indices into `scenes` (0..{len(refs) - 1}), "
                              f"got {index[:5].tolist()}")
        return [refs[i] for i in index.astype(np.int64)]
    raise SourceError(f"{where}: say which scene the trajectories were recorded in: a `scene` key, `scenes` with "
                      "`episode_scene`, or scene=REF on the command line")
