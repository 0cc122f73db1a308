"""One run's folder and its `run.json` record (DESIGN section 6).

`runs/<experiment>/<timestamp>/` holds `.hydra/config.yaml` (the resolved config) and
`.hydra/overrides.yaml`, `run.json`, `metrics.csv` (written by the CSV logger), `checkpoints/` and
whatever the run's evaluation writes. `run.json` is rewritten atomically on every update, so a reader
never sees half a record; its status is running, completed, failed (with the error) or interrupted.
The file names are defined here once.
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

__all__ = ["CHECKPOINTS_DIR", "CONFIG_DIR", "LAST_CHECKPOINT", "METRICS_CSV", "RUN_JSON", "STATUSES", "RunFolder",
           "runs_root"]

RUN_JSON = "run.json"
METRICS_CSV = "metrics.csv"
CHECKPOINTS_DIR = "checkpoints"
LAST_CHECKPOINT = "last.ckpt"
CONFIG_DIR = ".hydra"
STATUSES = ("running", "completed", "failed", "interrupted")


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="seconds")


def runs_root() -> Path:
    """`$SAMP_RUNS_DIR`, else `runs/` in the repository."""
    from samp.paths import REPO_ROOT

    return Path(os.environ.get("SAMP_RUNS_DIR", REPO_ROOT / "runs"))


class RunFolder:
    """A run folder and its record. `create` makes a fresh one; `RunFolder(path)` opens an existing one."""

    def __init__(self, path: Path | str):
        self.path = Path(path)
        if not self.path.is_dir():
            raise FileNotFoundError(f"run folder {self.path} does not exist")

    @classmethod
    def create(cls, root: Path | str, experiment: str) -> "RunFolder":
        """`<root>/<experiment>/<UTC timestamp>/`, with a numeric suffix if that second is taken."""
        if not experiment or "/" in experiment or experiment.startswith("."):
            raise ValueError(f"experiment name must be a plain folder name, got {experiment!r}")
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

    def read(self) -> dict:
        path = self.path / RUN_JSON
        return json.loads(path.read_text()) if path.is_file() else {}

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
        interrupted (Ctrl-C; Lightning turns it into SystemExit after a graceful shutdown)."""
        from samp.provenance import code_version, package_versions

        previous = self.read()
        starts = previous.get("starts", []) + [_now()]
        self.update(status="running", start=starts[0], starts=starts, end=None, error=None, host=platform.node(),
                    command=[Path(sys.argv[0]).name, *sys.argv[1:]], code_version=code_version(),
                    packages=package_versions(), **info)
        try:
            yield self
        except (KeyboardInterrupt, SystemExit):
            self.update(status="interrupted", end=_now())
            raise
        except BaseException as err:
            self.update(status="failed", end=_now(), error=f"{type(err).__name__}: {err}",
                        traceback=traceback.format_exc(limit=20))
            raise
        else:
            self.update(status="completed", end=_now())
