"""The work folder of a generation (`<root>/<name>/.work/<hash16>/`, `samp.data.generation`): who may write
into it, what is left over from a killed run, and which scene files count as finished.

  * One generation per shard at a time: a lock file `generate-<what>.lock` (`all`, or `shard<i>of<n>`),
    made like the merge lock (`samp.data.merging`: hard link or O_EXCL, holder's host, pid and start time,
    refreshed while held, taken over once its holder is gone). A second generation of the same scenes
    does not wait: it exits with one line naming the process that holds the lock. A generation of every
    scene and one of a shard cover the same scenes, so each refuses while the other runs; shards of one
    spec run side by side, as they are meant to.
  * Leftovers of a killed run (`*.tmp`: a scene file or sidecar being written) are removed before anything
    new is written, so a run that died of a full disk does not fail again on its own leftovers.
  * A scene counts as finished only when its file and sidecar are there, the file reads back in full (MCAP
    CRCs, every record decoded) and holds what its sidecar says. A damaged scene (a file truncated when the
    machine died, a flipped byte) is removed with one line and planned again; it is never merged.
"""

from __future__ import annotations

import json
import time
from contextlib import contextmanager
from pathlib import Path

from samp.data.merging import _create, _describe, _read, _stale, _take_over, held, lock_content
from samp.paths import unique_tmp

__all__ = ["SIDECAR", "GenerationBusy", "clear_stale", "damaged_scene", "generation_lock", "removed_on_error", "unfinished", "unique_tmp"]

SIDECAR = ".json"  # a scene file's sidecar: <file>.json, its wall-clock planner times and counts
TMP_STALE_S = 60.0  # a shared spec.json temporary older than this was left by a killed writer


class GenerationBusy(ValueError):
    """Another live process generates the same scenes into the same work folder; the message names it."""


def _lock_names(shard: int | None, num_shards: int) -> tuple[str, list[str]]:
    """(this generation's lock file name, the patterns of the lock files it may not run beside)."""
    if shard is None:
        return "generate-all.lock", ["generate-all.lock", "generate-shard*.lock"]
    own = f"generate-shard{shard}of{num_shards}.lock"
    return own, [own, "generate-all.lock"]


@contextmanager
def generation_lock(work: Path, name: str, shard: int | None = None, num_shards: int = 1):
    """Hold the generation lock of `shard` (None: every scene) of the work folder `work` for the block;
    GenerationBusy (one line naming the holder) while a live process holds it or a conflicting one."""
    own, conflicts = _lock_names(shard, num_shards)
    lock = work / own
    while True:
        content = lock_content()
        if _create(lock, content):
            break
        _refuse_or_take_over(lock, name, work)
    try:
        for pattern in conflicts:
            for other in work.glob(pattern):
                if other != lock:
                    _refuse_or_take_over(other, name, work)
    except BaseException:
        lock.unlink(missing_ok=True)
        raise
    with held(lock, content):
        yield


def _refuse_or_take_over(lock: Path, name: str, work: Path) -> None:
    """GenerationBusy when the holder of `lock` is alive; otherwise remove its stale lock file."""
    seen = _read(lock)
    if seen is None:  # released meanwhile
        return
    raw, holder, age = seen
    reason = _stale(holder, age)
    if reason is None:
        what = lock.name[len("generate-"):-len(".lock")]
        raise GenerationBusy(f"{name}: {_describe(holder)} is already generating {what} scenes into {work}; wait for "
                             f"it to finish or stop it (if it is gone, delete {lock} and run again)")
    _take_over(lock, raw, lock_content(), f"{name}: taking over the generation lock {lock} of {_describe(holder)}: "
                                          f"{reason}")


def clear_stale(work: Path, files: list[str]) -> int:
    """Remove what a killed run left while writing the scene files `files` (and their sidecars), and shared
    `spec.json` temporaries older than TMP_STALE_S; returns how many were removed."""
    removed = 0
    own = {f"{f}.tmp" for f in files} | {f"{f}{SIDECAR}.tmp" for f in files}
    for tmp in work.glob("*.tmp"):
        try:
            if tmp.name in own or (tmp.name.startswith("spec.json")
                                   and time.time() - tmp.stat().st_mtime > TMP_STALE_S):
                tmp.unlink()
                removed += 1
        except FileNotFoundError:
            pass
    return removed


def damaged_scene(work: Path, file: str) -> str | None:
    """Why the finished-looking scene `file` in `work` cannot be merged (unreadable, or not what its sidecar
    says), or None when it is intact. Reads the whole file with CRCs checked, grids included."""
    from samp.data.dataset import scene_count_problems
    from samp.data.mcap_io import read_scene_file

    try:
        sidecar = json.loads((work / (file + SIDECAR)).read_text())
    except (OSError, ValueError) as err:
        return f"its sidecar {file + SIDECAR} is unreadable ({type(err).__name__}: {err})"
    if not isinstance(sidecar, dict) or sidecar.get("file") != file:
        return f"its sidecar {file + SIDECAR} does not describe it"
    try:
        record = read_scene_file(work / file)  # every chunk, grids too: their CRCs are checked when decompressed
    except ValueError as err:
        return str(err).split("; it may be truncated")[0]
    try:
        problems = scene_count_problems(work, {"scenes": [sidecar]}, [record])
    except (KeyError, TypeError) as err:
        return f"its sidecar {file + SIDECAR} lacks {err}"
    return "; ".join(problems) or None


def unfinished(work: Path, jobs: list, label: str) -> list:
    """The jobs whose scene is not finished in `work`: file or sidecar missing, or damaged (removed here,
    with one line each, so that they are planned again)."""
    todo = []
    for job in jobs:
        path, sidecar = work / job.file, work / (job.file + SIDECAR)
        if not path.is_file() or not sidecar.is_file():
            todo.append(job)
            continue
        problem = damaged_scene(work, job.file)
        if problem is not None:
            print(f"{label}: {path} is damaged ({problem}); removing it: scene {job.index} is planned again",
                  flush=True)
            path.unlink(missing_ok=True)
            sidecar.unlink(missing_ok=True)
            todo.append(job)
    return todo


@contextmanager
def removed_on_error(tmp: Path, *also: Path):
    """Remove the temporary file `tmp` (and the files `also`) when the block fails (a full disk, Ctrl-C): no
    partial output stays. An OSError of a write names no file (a full disk while writing); it is raised
    again naming `tmp`."""
    try:
        yield
    except BaseException as err:
        for path in (tmp, *also):
            path.unlink(missing_ok=True)
        if isinstance(err, OSError) and err.filename is None:
            raise OSError(err.errno, err.strerror, str(tmp)) from None
        raise


def write_json(path: Path, data: dict, shared: bool = False) -> None:
    """Write `data` to `path` atomically; `shared`: a file several processes may write (a unique temporary)."""
    tmp = unique_tmp(path) if shared else path.with_name(path.name + ".tmp")
    with removed_on_error(tmp):
        tmp.write_text(json.dumps(data, indent=1, sort_keys=True))
        tmp.replace(path)
