"""Policy runs on a remote: `push_run` and `pull_run` (docs/runs.md, "Sharing runs"; the layout in
docs/design.md, "Remotes").

A run folder `<runs root>/EXPERIMENT/RUN/` lives on a remote as `<remote>/runs/EXPERIMENT/RUN/index.json`
plus the blobs of every file in it: its checkpoints, `run.json`, its card, `.hydra/`, metrics, plots and
evaluation reports. Only an ended run is pushed (its status is not `running`), after its checkpoints were
checked against the sha256 that `run.json` recorded (`files_sha256`). A pull lands in
`<runs root>/EXPERIMENT/.pull-RUN/`, each file checked against the index as it arrives, then every file
`run.json` recorded is checked against that record, and the folder is renamed into place.
"""

from __future__ import annotations

import shutil
from pathlib import Path

from samp.integrity import FILES_SHA256
from samp.names import RUN_JSON
from samp.paths import check_name, file_sha256
from samp.remote import RemoteError, join, pull_folder, push_folder, read_index

__all__ = ["RUNS", "pull_run", "push_run", "run_entry"]

RUNS = "runs"  # the folder of run entries on a remote


def run_entry(folder: Path, record: dict) -> str:
    """`runs/EXPERIMENT/RUN` for a run folder (its experiment from run.json, else its parent folder's name)."""
    experiment = str(record.get("experiment") or folder.parent.name)
    return f"{RUNS}/{check_name(experiment, 'experiment name')}/{check_name(folder.name, 'run folder name')}"


def _files(folder: Path) -> dict[str, dict]:
    """{path inside the run folder: {"sha256", "size"}} of every file in it."""
    return {p.relative_to(folder).as_posix(): {"sha256": file_sha256(p), "size": p.stat().st_size}
            for p in sorted(folder.rglob("*")) if p.is_file()}


def push_run(folder: Path, remote: str, force: bool = False) -> tuple[str, int, int]:
    """Upload the ended run in `folder` to `remote` (`force`: every file, also those already there).
    Returns (the entry's URL, files uploaded, files already there)."""
    from samp.integrity import check_recorded_hash
    from samp.runs.folder import RunFolder

    folder = Path(folder)
    record = RunFolder(folder).read()
    if not record:
        raise FileNotFoundError(f"{folder} is not a run folder: it has no {RUN_JSON}")
    if record.get("status") in (None, "running"):
        raise ValueError(f"run {folder} is still running (or its {RUN_JSON} says no status): push it once it ended")
    for rel in sorted(record.get(FILES_SHA256) or {}):
        check_recorded_hash(folder / rel)  # IntegrityError naming the file: a damaged run is not shared
    entry = run_entry(folder, record)
    sent, kept = push_folder(folder, _files(folder), remote, entry, {"kind": "run", "ref": entry.split("/", 1)[1]},
                             force)
    return join(remote, entry), sent, kept


def _split(ref: str, remote: str | None) -> tuple[str, str, str]:
    """(remote, EXPERIMENT, RUN) from `EXPERIMENT/RUN` with `remote`, or from `<remote>/runs/EXPERIMENT/RUN`."""
    if "://" in ref:
        head, sep, tail = ref.rstrip("/").rpartition(f"/{RUNS}/")
        remote, ref = (head, tail) if sep else (None, ref)
    parts = ref.strip("/").split("/")
    if not remote or len(parts) != 2:
        raise ValueError(f"say which run to pull: run=EXPERIMENT/RUN remote=URL, or run=<remote>/{RUNS}/EXPERIMENT/RUN "
                         f"(got run={ref!r}{f' remote={remote}' if remote else ''})")
    return remote, check_name(parts[0], "experiment name"), check_name(parts[1], "run folder name")


def pull_run(ref: str, remote: str | None = None, root: Path | None = None) -> tuple[Path, int, int]:
    """Pull the run `ref` (EXPERIMENT/RUN with `remote`, or its URL) into `root` (default: the runs folder).
    Returns (the run folder, files downloaded, files kept); (folder, 0, 0) when it is here already."""
    from samp.runs.folder import runs_root

    remote, experiment, name = _split(ref, remote)
    dest = (Path(root) if root else runs_root()) / experiment / name
    if (dest / RUN_JSON).is_file():
        return dest, 0, 0
    entry = f"{RUNS}/{experiment}/{name}"
    index = read_index(remote, entry)
    staging = dest.with_name(f".pull-{name}")
    got, kept = pull_folder(remote, entry, index, staging)
    _check_record(staging, join(remote, entry))
    try:
        staging.rename(dest)
    except OSError:
        if not (dest / RUN_JSON).is_file():
            raise
        shutil.rmtree(staging)
    return dest, got, kept


def _check_record(staging: Path, url: str) -> None:
    """Every file the pulled run.json recorded is there with the recorded sha256 (RemoteError otherwise)."""
    from samp.runs.folder import DamagedRecord, RunFolder

    try:
        record = RunFolder(staging).read()
    except DamagedRecord as err:
        raise RemoteError(f"{url}: {err}") from None
    if not record:
        raise RemoteError(f"{url} holds no {RUN_JSON}: it is not a run; push the run folder again")
    for rel, expected in sorted((record.get(FILES_SHA256) or {}).items()):
        path = staging / rel
        actual = file_sha256(path) if path.is_file() else "missing"
        if actual != expected:
            raise RemoteError(f"remote file {rel} of {url} is not the file its {RUN_JSON} recorded: sha256 expected "
                              f"{expected}, actual {actual}; nothing was published locally. Push the run again with force=true")
