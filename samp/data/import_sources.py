"""Reading demonstrations recorded elsewhere: `.npz`, HDF5 and LeRobot folders -> `Recorded` trajectories in
the robot's joint order (the keys are listed in `samp.data.importing` and docs/datasets.md). Declared sizes are
bounded before anything is read; an `.npz` is read without pickle."""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

__all__ = ["MAX_NPZ_BYTES", "MAX_SOURCE_ROWS", "Recorded", "read_source"]

MAX_SOURCE_ROWS = 50_000_000  # joint-position rows a source may declare: larger is refused before reading
MAX_NPZ_BYTES = 4 << 30  # what the arrays of an .npz may take once decompressed: larger is refused before reading


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
        return _read_lerobot(path, robot, scene, key, columns)
    if not path.is_file():
        raise FileNotFoundError(f"import source {path} does not exist")
    suffix = path.suffix.lower()
    if suffix == ".npz":
        _check_npz_size(path)
        try:
            with np.load(path, allow_pickle=False) as data:  # no pickles: a source file never runs code
                arrays = {k: data[k] for k in data.files}
        except ValueError as err:  # object arrays (ragged trajectories saved as a list) need pickle
            raise ValueError(f"import source {path}: {err}; store trajectories as joint_positions (N, n) with "
                             "episode_ends, not as an object array") from None
    elif suffix in (".h5", ".hdf5"):
        arrays = _read_hdf5(path)
    else:
        raise ValueError(f"import source {path}: unknown format {suffix!r}; expected .npz, .h5/.hdf5 or a LeRobot "
                         "dataset folder")
    return _from_arrays(arrays, path, robot, scene, columns)


def _check_npz_size(path: Path) -> None:
    """Refuse an .npz whose members would decompress to more than MAX_NPZ_BYTES (a zip bomb), before reading."""
    import zipfile

    try:
        with zipfile.ZipFile(path) as archive:
            declared = sum(info.file_size for info in archive.infolist())
    except zipfile.BadZipFile as err:
        raise ValueError(f"import source {path} is not a readable .npz (a zip archive): {err}") from None
    if declared > MAX_NPZ_BYTES:
        raise ValueError(f"import source {path} declares {declared} bytes of arrays, more than the {MAX_NPZ_BYTES} an "
                         "import reads; split it into several files")


def _read_hdf5(path: Path) -> dict:
    try:
        import h5py
    except ImportError:
        raise ImportError("reading HDF5 needs h5py: pip install 'samp[import]' (or h5py)") from None
    with h5py.File(path, "r") as f:
        out = {}
        for k in ("joint_positions", "episode_ends", "scene", "scenes", "episode_scene", "timestamps", "joint_names"):
            if k in f:
                if k == "joint_positions" and int(np.prod(f[k].shape)) > MAX_SOURCE_ROWS * 64:
                    raise ValueError(f"{path}: joint_positions declares shape {f[k].shape}, beyond the import limit")
                value = f[k][()]
                out[k] = np.array([v.decode() if isinstance(v, bytes) else v for v in np.atleast_1d(value)]) \
                    if k in ("scene", "scenes", "joint_names") else np.asarray(value)
        return out


def _columns(names: list[str] | None, width: int, robot, columns: list[int] | None, where: str) -> list[int]:
    """Which source columns are the robot's joints, in the robot's order."""
    n = robot.dof
    if columns is not None:
        if len(columns) != n or not all(0 <= c < width for c in columns):
            raise ValueError(f"{where}: columns={columns} must list {n} column indices below {width}")
        return list(columns)
    if names:
        missing = [j for j in robot.joint_names if j not in names]
        if missing:
            raise ValueError(f"{where}: the source's joints {names} lack the robot's {missing}; give columns=i,j,... "
                             f"for the {n} joints {robot.joint_names}")
        return [names.index(j) for j in robot.joint_names]
    if width < n:
        raise ValueError(f"{where}: {width} columns, but robot {robot.name!r} has {n} joints")
    return list(range(n))


def _from_arrays(arrays: dict, path: Path, robot, scene: str | None, columns: list[int] | None) -> list[Recorded]:
    where = str(path)
    if "joint_positions" not in arrays:
        raise ValueError(f"{where}: no `joint_positions` array (keys: {sorted(arrays)}); see docs/datasets.md")
    q = np.asarray(arrays["joint_positions"], dtype=np.float64)
    names = [str(s) for s in arrays["joint_names"]] if "joint_names" in arrays else None
    if q.ndim == 3:
        episodes = list(q)
    elif q.ndim == 2 and "episode_ends" in arrays:
        ends = np.asarray(arrays["episode_ends"], dtype=np.int64)
        if len(ends) == 0 or np.any(np.diff(ends) <= 0) or ends[0] <= 0 or ends[-1] != len(q):
            raise ValueError(f"{where}: episode_ends must increase strictly and end at the row count {len(q)}, got "
                             f"{ends[:5].tolist()}...{ends[-1:].tolist()}")
        episodes = np.split(q, ends[:-1])
    else:
        raise ValueError(f"{where}: joint_positions must be (K, T, n), or (N, n) with episode_ends; got {q.shape}")
    cols = _columns(names, q.shape[-1], robot, columns, where)
    stamps = arrays.get("timestamps")
    if stamps is not None:
        stamps = np.asarray(stamps, dtype=np.float64)
        stamps = list(stamps) if stamps.ndim == 2 else np.split(stamps, np.cumsum([len(e) for e in episodes])[:-1])
    scenes = _scene_refs(arrays, len(episodes), scene, where)
    return [Recorded(e[:, cols], scenes[k], f"{path.name}#{k}", None if stamps is None else stamps[k])
            for k, e in enumerate(episodes)]


def _scene_refs(arrays: dict, count: int, scene: str | None, where: str) -> list[str]:
    if scene is not None:
        return [scene] * count
    if "scene" in arrays:
        return [str(np.atleast_1d(arrays["scene"])[0])] * count
    if "scenes" in arrays and "episode_scene" in arrays:
        refs, index = [str(s) for s in arrays["scenes"]], np.asarray(arrays["episode_scene"], dtype=np.int64)
        if len(index) != count or index.min() < 0 or index.max() >= len(refs):
            raise ValueError(f"{where}: episode_scene must hold {count} indices into scenes (0..{len(refs) - 1})")
        return [refs[i] for i in index]
    raise ValueError(f"{where}: say which scene the trajectories were recorded in: a `scene` key, `scenes` with "
                     "`episode_scene`, or scene=REF on the command line")


def _read_lerobot(folder: Path, robot, scene: str | None, key: str, columns: list[int] | None) -> list[Recorded]:
    info_path = folder / "meta" / "info.json"
    if not info_path.is_file():
        raise ValueError(f"{folder} is not a LeRobot dataset: it has no meta/info.json")
    if scene is None:
        raise ValueError(f"{folder}: a LeRobot dataset does not say which samp scene it was recorded in; give scene=REF")
    try:
        import pyarrow.parquet as pq
    except ImportError:
        raise ImportError("reading LeRobot datasets needs pyarrow: pip install 'samp[import]' (or pyarrow)") from None
    info = json.loads(info_path.read_text())
    feature = (info.get("features") or {}).get(key)
    if feature is None:
        raise ValueError(f"{folder}: meta/info.json has no feature {key!r}; features: {sorted(info.get('features') or {})}")
    names = feature.get("names")
    names = names.get("motors") if isinstance(names, dict) else names  # older LeRobot versions nest them
    files = sorted((folder / "data").rglob("*.parquet"))
    if not files:
        raise ValueError(f"{folder}: no parquet files under data/")
    rows: dict[int, list] = {}
    for f in files:
        table = pq.read_table(f, columns=[key, "episode_index", "frame_index", "timestamp"])
        for s, e, i, t in zip(*(table.column(c).to_pylist() for c in (key, "episode_index", "frame_index", "timestamp"))):
            rows.setdefault(int(e), []).append((int(i), float(t), s))
    out = []
    for episode in sorted(rows):
        frames = sorted(rows[episode])
        state = np.asarray([s for _, _, s in frames], dtype=np.float64)
        cols = _columns(list(names) if names else None, state.shape[1], robot, columns, str(folder))
        out.append(Recorded(state[:, cols], scene, f"{folder.name}#episode{episode}",
                            np.asarray([t for _, t, _ in frames])))
    return out
