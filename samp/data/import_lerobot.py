"""Reading a LeRobot-format dataset folder (`meta/info.json`, `data/**/*.parquet`) -> `Recorded` trajectories.

The folder is untrusted input (docs/integrity.md): a symbolic link anywhere in it that leads outside it is
refused (an import would otherwise read, hash and publish a file the folder only points at); `meta/info.json`
is bounded in size and its fields' types checked; every parquet file's schema and declared sizes (rows and
values, from its metadata) are checked before a column is read."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from samp.data.import_sources import (MAX_SOURCE_BYTES, MAX_SOURCE_EPISODES, Recorded, SourceError, columns_for,
                                      first_line)

__all__ = ["MAX_INFO_BYTES", "read_lerobot"]

MAX_INFO_BYTES = 1 << 20  # meta/info.json: a description of the features, a few kilobytes in practice
INDEX_COLUMNS = ("episode_index", "frame_index", "timestamp")


def read_lerobot(folder: Path, robot, scene: str | None, key: str, columns: list[int] | None) -> list[Recorded]:
    """The episodes of a LeRobot folder, each ordered by frame_index, its `key` columns in the robot's order."""
    files = _files_inside(folder)
    info_path = folder / "meta" / "info.json"
    if not info_path.is_file():
        raise SourceError(f"{folder} is not a LeRobot dataset: it has no meta/info.json")
    if scene is None:
        raise SourceError(f"{folder}: a LeRobot dataset does not say which samp scene it was recorded in; give "
                          "scene=REF")
    try:
        import pyarrow  # noqa: F401
    except ImportError:
        raise ImportError("reading LeRobot datasets needs pyarrow: pip install 'samp[import]' (or pyarrow)") from None
    names = _feature_names(info_path, key)
    parquet = sorted(f for f in files if f.suffix == ".parquet" and f.relative_to(folder).parts[0] == "data")
    if not parquet:
        raise SourceError(f"{folder}: no parquet files under data/")
    declared = sum(_declared_bytes(f, key) for f in parquet)
    if declared > MAX_SOURCE_BYTES:
        raise SourceError(f"{folder}: its parquet files declare {declared} bytes of {key!r} and index columns, more "
                          f"than the {MAX_SOURCE_BYTES} an import reads per source (MAX_SOURCE_BYTES); import it in "
                          "parts")
    parts = [_read_parquet(f, key) for f in parquet]
    widths = {p[0].shape[1] for p in parts if len(p[0])}
    if len(widths) > 1:
        raise SourceError(f"{folder}: the parquet files hold {sorted(widths)} values of {key!r} per frame, expected "
                          "the same in every file")
    if not widths:
        return []
    state = np.concatenate([p[0] for p in parts if len(p[0])])  # (N, width)
    episode, frame, stamp = (np.concatenate([p[i] for p in parts if len(p[0])]) for i in (1, 2, 3))  # (N,) each
    cols = columns_for(names, state.shape[1], robot, columns, f"{folder} (feature {key!r})",
                       names_key=f"meta/info.json's `names` of {key!r}")
    order = np.lexsort((frame, episode))
    starts = np.flatnonzero(np.diff(episode[order], prepend=episode[order][:1] - 1))
    if len(starts) > MAX_SOURCE_EPISODES:
        raise SourceError(f"{folder}: holds {len(starts)} episodes, more than the {MAX_SOURCE_EPISODES} an import "
                          "reads per source (MAX_SOURCE_EPISODES); import it in parts")
    return [Recorded(state[rows][:, cols], scene, f"{folder.name}#episode{episode[rows[0]]}", stamp[rows])
            for rows in np.split(order, starts[1:])]


def _files_inside(folder: Path) -> list[Path]:
    """Every file under `folder`, refusing a symbolic link (to a file or a folder) that leads outside it or
    nowhere; links to folders inside are not descended (their files are there already)."""
    root = folder.resolve()
    out = []
    for top, dirs, names in os.walk(folder):
        for name in dirs + names:
            path = Path(top) / name
            if path.is_symlink():
                try:
                    target = path.resolve(strict=True)
                except (OSError, RuntimeError):  # dangling, or a loop of links
                    raise SourceError(f"{folder}: {path} is a symbolic link that leads nowhere; remove it") from None
                if not target.is_relative_to(root):
                    raise SourceError(f"{folder}: {path} is a symbolic link to {target}, outside the dataset folder; "
                                      "an import reads only the folder's own files: copy the file in")
            if name in names:
                out.append(path)
    return out


def _feature_names(info_path: Path, key: str) -> list[str] | None:
    """The joint names meta/info.json gives feature `key` (None when it gives none)."""
    size = info_path.stat().st_size
    if size > MAX_INFO_BYTES:
        raise SourceError(f"{info_path}: {size} bytes, more than the {MAX_INFO_BYTES} a LeRobot info.json may take "
                          "(MAX_INFO_BYTES)")
    try:
        info = json.loads(info_path.read_text())
    except (ValueError, RecursionError) as err:  # not UTF-8, not JSON, or nested past the parser's depth
        raise SourceError(f"{info_path} is not readable JSON: {first_line(err)}") from None
    features = info.get("features") if isinstance(info, dict) else None
    if not isinstance(features, dict):
        raise SourceError(f"{info_path}: expected an object with a `features` object, got {type(info).__name__}"
                          + ("" if not isinstance(info, dict) else f" whose `features` is {type(features).__name__}"))
    feature = features.get(key)
    if feature is None:
        raise SourceError(f"{info_path}: no feature {key!r} in `features`; features: {sorted(features)[:20]}")
    if not isinstance(feature, dict):
        raise SourceError(f"{info_path}: `features.{key}` is {type(feature).__name__}, expected an object")
    names = feature.get("names")
    names = names.get("motors") if isinstance(names, dict) else names  # older LeRobot versions nest them
    if names is None:
        return None
    if not isinstance(names, list) or not all(isinstance(n, str) for n in names):
        raise SourceError(f"{info_path}: `features.{key}.names` must be a list of joint names, got "
                          f"{json.dumps(names)[:80]}")
    return names


def _declared_bytes(path: Path, key: str) -> int:
    """What reading `key` and the index columns of one parquet file will take, from its metadata and schema
    (checked: `key` a list of numbers per frame, the indices integers, the timestamps numbers)."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    try:
        meta = pq.ParquetFile(path).metadata
        schema = meta.schema.to_arrow_schema()
    except (pa.ArrowException, OSError) as err:
        raise SourceError(f"{path} is not a readable parquet file: {first_line(err)}") from None
    missing = [c for c in (key, *INDEX_COLUMNS) if c not in schema.names]
    if missing:
        raise SourceError(f"{path}: no column {missing} (columns: {schema.names[:20]}); a LeRobot data file holds "
                          f"{key!r}, {', '.join(INDEX_COLUMNS)}")
    kind = schema.field(key).type
    if not (pa.types.is_list(kind) or pa.types.is_large_list(kind) or pa.types.is_fixed_size_list(kind)):
        what = "one number per frame (a scalar feature)" if _is_number(kind) else f"{kind}"
        raise SourceError(f"{path}: column {key!r} is {what}; expected a list of joint positions per frame")
    if not _is_number(kind.value_type):
        raise SourceError(f"{path}: column {key!r} holds lists of {kind.value_type}, expected lists of numbers")
    for c in INDEX_COLUMNS:
        if not (pa.types.is_integer(schema.field(c).type) or (c == "timestamp" and _is_number(schema.field(c).type))):
            raise SourceError(f"{path}: column {c!r} is {schema.field(c).type}, expected "
                              f"{'numbers' if c == 'timestamp' else 'integers'}")
    values = sum(meta.row_group(g).column(c).num_values for g in range(meta.num_row_groups)
                 for c in range(meta.num_columns) if meta.row_group(g).column(c).path_in_schema.startswith(key + "."))
    return 8 * (values + len(INDEX_COLUMNS) * meta.num_rows)  # each read as float64 or int64


def _is_number(kind) -> bool:
    import pyarrow as pa

    return pa.types.is_integer(kind) or pa.types.is_floating(kind)


def _read_parquet(path: Path, key: str) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """-> state (N, width) float64, episode_index (N,) and frame_index (N,) int64, timestamp (N,) float64."""
    import pyarrow as pa
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    try:
        table = pq.read_table(path, columns=[key, *INDEX_COLUMNS])
        state = table.column(key).combine_chunks()
        lengths = pc.list_value_length(state).to_numpy(zero_copy_only=False)
        if table.num_rows and (state.null_count or lengths.min() != lengths.max()):
            raise SourceError(f"{path}: column {key!r} must hold the same number of values in every frame, holds "
                              f"{'nulls' if state.null_count else f'{lengths.min()} to {lengths.max()}'}")
        width = int(lengths[0]) if table.num_rows else 0
        flat = state.flatten().to_numpy(zero_copy_only=False).astype(np.float64)  # nulls inside read as NaN
        index = []
        for c in INDEX_COLUMNS:
            column = table.column(c)
            if column.null_count:
                raise SourceError(f"{path}: column {c!r} has {column.null_count} empty (null) entries")
            index.append(column.to_numpy())
    except (pa.ArrowException, OSError) as err:
        raise SourceError(f"{path}: cannot read its columns: {first_line(err)}") from None
    episode, frame = (_int64(path, c, a) for c, a in zip(INDEX_COLUMNS[:2], index[:2]))
    return flat.reshape(len(episode), width), episode, frame, index[2].astype(np.float64)


def _int64(path: Path, column: str, values: np.ndarray) -> np.ndarray:
    """An index column as int64, refusing a uint64 beyond int64 (it would wrap, merging distinct episodes)."""
    if values.dtype == np.uint64 and len(values) and values.max() > np.iinfo(np.int64).max:
        raise SourceError(f"{path}: column {column!r} holds {int(values.max())}, beyond the int64 range of an index")
    return values.astype(np.int64)
