"""One run's folder and its `run.json` record (docs/design.md section 6).

`runs/<experiment>/<timestamp>/` holds `.hydra/config.yaml` (the resolved config) and
`.hydra/overrides.yaml`, `run.json`, `metrics.csv` (written by the CSV logger), `checkpoints/` and
whatever the run's evaluation writes. `run.json` is rewritten atomically on every update, so a reader
never sees half a record; its status is running, completed, failed (with the error) or interrupted.
The file names are defined once, in `samp.names`.
"""

from __future__ import annotations

import json
import os
import platform
import sys
import traceback
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

__all__ = ["CHECKPOINTS_DIR", "CONFIG_DIR", "LAST_CHECKPOINT", "METRICS_CSV", "RUN_JSON", "STATUSES", "DamagedRecord",
           "RunFolder", "Terminated", "runs_root"]

from samp.names import CHECKPOINTS_DIR, CONFIG_DIR, LAST_CHECKPOINT, METRICS_CSV, RUN_JSON

STATUSES = ("running", "completed", "failed", "interrupted")


class DamagedRecord(ValueError):
    """A run.json that is not a JSON object of the expected shape (its path and what is wrong in the message)."""


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def runs_root() -> Path:
    """`$SAMP_RUNS_DIR`, else `runs/` in the repository."""
    from samp.paths import runs_root as root

    return root()


class RunFolder:
    """A run folder and its record. `create` makes a fresh one; `RunFolder(path)` opens an existing one."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"run folder {self.path} does not exist")

    @classmethod
    def create(cls, root: Path | str, experiment: str) -> "RunFolder":
        """`<root>/<experiment>/<UTC timestamp>/`, with a numeric suffix if that second is taken."""
        from samp.paths import check_name

        check_name(experiment, "experiment name")
        parent = Path(root) / experiment
        parent.mkdir(parents=True, exist_ok=True)
        stamp = datetime.now(timezone.utc).strftime("%Y-%m-%d_%H-%M-%S")
        for k in range(1000):
            path = parent / (stamp if k == 0 else f"{stamp}_{k}")
            try:
                path.mkdir()
                return cls(path)
            except FileExistsError:
                continue
        raise RuntimeError(f"could not create a new run folder under {parent}")

    @classmethod
    def create_at(cls, path: Path | str) -> "RunFolder":
        """A new run in exactly `path` (a sweep member's folder): created if missing; refused when it
        already holds a run, which is never overwritten."""
        path = Path(path)
        if (path / RUN_JSON).is_file():
            status = RunFolder(path).read().get("status")
            raise ValueError(f"{path} already holds a run (status {status}); continue it with resume={path}, "
                             "or choose another run_dir")
        path.mkdir(parents=True, exist_ok=True)
        return cls(path)

    # ----------------------------------------------------------------- files
    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINTS_DIR

    @property
    def last_checkpoint(self) -> Path:
        return self.checkpoints / LAST_CHECKPOINT

    def write_config(self, resolved_yaml: str, overrides: list[str]) -> None:
        folder = self.path / CONFIG_DIR
        folder.mkdir(exist_ok=True)
        (folder / "config.yaml").write_text(resolved_yaml)
        (folder / "overrides.yaml").write_text("".join(f"- {o}\n" for o in overrides) or "[]\n")

    def trim_metrics(self, step: int) -> int:
        """Before a resumed run continues metrics.csv: rows logged after the checkpoint it resumes from
        (their `step` is >= `step`) are redone, so they move to metrics.superseded.csv. Returns how many."""
        import csv

        path = self.path / METRICS_CSV
        if not path.is_file():
            return 0
        with open(path, newline="") as f:
            reader = csv.DictReader(f)
            header, rows = list(reader.fieldnames or []), list(reader)
        keep, dropped = [], []
        for row in rows:
            (keep if not row.get("step") or int(float(row["step"])) < step else dropped).append(row)
        if not dropped:
            return 0
        superseded = self.path / "metrics.superseded.csv"
        with open(superseded, "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=header)
            if f.tell() == 0:
                writer.writeheader()
            writer.writerows(dropped)
        tmp = self.path / f".{METRICS_CSV}.tmp"
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=header)
            writer.writeheader()
            writer.writerows(keep)
        tmp.replace(path)
        return len(dropped)

    def read(self) -> dict:
        """The record ({} before the first one); DamagedRecord naming the file when it is not a JSON
        object, or when its config or metrics are not objects."""
        path = self.path / RUN_JSON
        if not path.is_file():
            return {}
        try:
            record = json.loads(path.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as err:
            raise DamagedRecord(f"{path} is not valid JSON ({err}); the run record is damaged: restore it, or move the "
                                "run folder away") from None
        if not isinstance(record, dict):
            raise DamagedRecord(f"{path} holds a JSON {type(record).__name__}, not a run record (an object); restore it, "
                                "or move the run folder away")
        for key in ("config", "metrics"):
            if record.get(key) is not None and not isinstance(record[key], dict):
                raise DamagedRecord(f"{path}: '{key}' is a {type(record[key]).__name__}, not an object; the run record "
                                    "is damaged: restore it, or move the run folder away")
        return record

    def update(self, **fields) -> dict:
        """Merge `fields` into run.json (written to a temporary file, then renamed into place)."""
        record = {**self.read(), **fields}
        if "status" in record and record["status"] not in STATUSES:
            raise ValueError(f"run status must be one of {STATUSES}, got {record['status']!r}")
        tmp = self.path / f".{RUN_JSON}.tmp"
        tmp.write_text(json.dumps(record, indent=2, sort_keys=True, default=str))
        tmp.replace(self.path / RUN_JSON)
        return record

    # ----------------------------------------------------------------- lifetime
    @contextmanager
    def record(self, **info):
        """Mark the run running (with provenance and `info`) for the block, then completed, failed or
        interrupted: Ctrl-C (Lightning turns it into SystemExit after a graceful shutdown) or SIGTERM
        (what `kill`, SLURM and job schedulers send; raised here as `Terminated`)."""
        from samp.provenance import code_version, package_versions

        previous = self.read()
        starts = previous.get("starts", []) + [_now()]
        self.update(status="running", start=starts[0], starts=starts, end=None, error=None, host=platform.node(),
                    pid=os.getpid(), command=[Path(sys.argv[0]).name, *sys.argv[1:]], code_version=code_version(),
                    packages=package_versions(), **info)
        try:
            with _sigterm_raises():
                yield self
        except (KeyboardInterrupt, SystemExit, Terminated):
            self.update(status="interrupted", end=_now(), **self._hashes())
            raise
        except BaseException as err:
            self.update(status="failed", end=_now(), error=f"{type(err).__name__}: {err}",
                        traceback=traceback.format_exc(limit=20), **self._hashes())
            raise
        else:
            self.update(status="completed", end=_now(), **self._hashes())

    def _hashes(self) -> dict:
        """{"files_sha256": ...}: the sha256 of the run's checkpoints and artifacts as the run ends, which
        loading them checks (`samp.integrity.check_recorded_hash`)."""
        from samp.integrity import FILES_SHA256, hash_run_files

        return {FILES_SHA256: hash_run_files(self.path)}


class Terminated(BaseException):
    """The process received SIGTERM inside `RunFolder.record` (a BaseException, like KeyboardInterrupt,
    so that `except Exception` in library code does not swallow it)."""


@contextmanager
def _sigterm_raises():
    """Within the block, SIGTERM raises `Terminated` in the main thread (elsewhere signals cannot be set,
    and the block runs unchanged). Lightning, during `fit`, calls its own handler first, then this one."""
    import signal
    import threading

    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def _raise(signum, frame):
        raise Terminated(f"received signal {signum} (SIGTERM)")

    before = signal.signal(signal.SIGTERM, _raise)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, before)
