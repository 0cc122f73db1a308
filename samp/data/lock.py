"""Pinned inputs: reading the lock file that `python -m samp.train experiment=NAME --lock` writes (samp/train/lock.py)
and later runs honour
(docs/datasets.md, "Pinning inputs"; the format in docs/design.md, "Lock file").

Without a lock a bare dataset name means the newest dataset of that name, which changes when someone
generates or pulls another. The lock file records, for one experiment, the exact `NAME@ID` of each
input a bare name stood for when it was written: the training dataset, the benchmark's dataset and the
robot SDF (`NAME@ARTIFACT_ID`). While a lock is in effect a bare name it pins resolves to that id and to
nothing else: when that id is not here, the error says how to pull or generate it. The lock in effect is
`$SAMP_LOCK` (a path; empty or `none` for no lock), else `samp.lock` in the current folder when it
exists. Runs record the lock they ran under in `run.json` (`lock`: path, sha256, entries).
"""

from __future__ import annotations

import hashlib
import json
import os
from pathlib import Path

__all__ = ["KINDS", "LOCK_ENV", "LOCK_FILE", "LOCK_FORMAT", "active_lock", "is_pinned", "lock_record", "locked", "read_lock"]

LOCK_FILE = "samp.lock"
LOCK_ENV = "SAMP_LOCK"
LOCK_FORMAT = 1
KINDS = ("datasets", "robot_sdf")


def active_lock() -> Path | None:
    """The lock file in effect (module docstring), or None. A `$SAMP_LOCK` that names no file is an error."""
    env = os.environ.get(LOCK_ENV)
    if env is not None:
        if env.strip().lower() in ("", "none"):
            return None
        path = Path(env).expanduser()
        if not path.is_file():
            raise FileNotFoundError(f"{LOCK_ENV}={env} names no file; write it with `python -m samp.train "
                                    f"experiment=NAME --lock={env}`, or unset {LOCK_ENV}")
        return path
    path = Path.cwd() / LOCK_FILE
    return path if path.is_file() else None


def read_lock(path: Path) -> dict:
    """The lock file's content, checked: ValueError naming the file and what is wrong."""
    try:
        data = json.loads(Path(path).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ValueError(f"lock file {path} is not valid JSON ({err}); write it again with `python -m samp.train experiment=NAME --lock`") from None
    if not isinstance(data, dict) or data.get("format_version") != LOCK_FORMAT or \
            not all(isinstance(data.get(k, {}), dict) for k in KINDS):
        raise ValueError(f"lock file {path} is not a samp lock of format version {LOCK_FORMAT}; write it again with "
                         "`python -m samp.train experiment=NAME --lock`")
    return data


def locked(kind: str, name: str) -> tuple[str, Path] | None:
    """(the pinned `NAME@ID`, the lock file) for a bare `name` of `kind` ("datasets" | "robot_sdf"), or None."""
    path = active_lock()
    if path is None:
        return None
    ref = read_lock(path).get(kind, {}).get(name)
    return (ref, path) if ref else None


def is_pinned(name: str) -> bool:
    """Whether the lock file in effect pins the bare dataset name `name`."""
    return locked("datasets", name) is not None


def lock_record() -> dict | None:
    """What a run records of the lock it ran under: {"path", "sha256", "datasets", "robot_sdf"}, or None."""
    path = active_lock()
    if path is None:
        return None
    data = read_lock(path)
    return {"path": str(path.resolve()), "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
            **{k: data.get(k, {}) for k in KINDS}}
