"""The run registry: every folder with a run.json under a root, read into `Run`s that answer any key.

A run's keys are one flat namespace: its resolved config as dotted keys (`datamodule.n_e`, `name`,
`system.collision_loss`), its record (`status`, `experiment`, `seed`, `dataset_id`, `fit_time_s`,
`code_version.git_commit`, `sweep.member`, ...) and its final metrics (`val/loss`,
`eval/samp/heldout/success_rate`, ...). `--by`, filters and table columns all use these keys.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

from samp.runs.folder import METRICS_CSV, RUN_JSON, RunFolder
from samp.runs.lineage import flatten

__all__ = ["EVAL_METRICS", "Run", "check_key", "find_runs", "load_run", "matches", "varying_keys"]

EVAL_METRICS = Path("eval") / "metrics.json"  # written by `python -m samp.eval` (samp.eval.names)
HIDDEN = ("config", "metrics", "packages", "traceback", "command", "starts", "loggers")  # not keys of their own


@dataclass
class Run:
    """One run folder, read once."""

    path: Path
    record: dict = field(repr=False)

    @cached_property
    def values(self) -> dict:
        """Config and record as dotted keys (the record wins where both have a key, e.g. `seed`)."""
        record = {k: v for k, v in self.record.items() if k not in HIDDEN}
        return {**flatten(self.record.get("config") or {}), **flatten(record)}

    @property
    def metrics(self) -> dict:
        return self.record.get("metrics") or {}

    @property
    def name(self) -> str:
        """`<parent>/<folder>` (an experiment and timestamp, or a sweep and member)."""
        return f"{self.path.parent.name}/{self.path.name}"

    @property
    def status(self) -> str:
        return self.record.get("status", "?")

    @property
    def robot(self) -> str | None:
        return self.values.get("robot.name") or self.values.get("system.robot")

    def get(self, key: str):
        """A metric, a config key or a record key; None when the run has no such key."""
        return self.metrics[key] if key in self.metrics else self.values.get(key)

    def has(self, key: str) -> bool:
        return key in self.metrics or key in self.values

    @cached_property
    def evaluation(self) -> dict | None:
        """The run's eval/metrics.json (per split, the planner's and the expert's metrics), if any."""
        path = self.path / EVAL_METRICS
        return json.loads(path.read_text()) if path.is_file() else None

    def curves(self) -> list[dict]:
        """metrics.csv as rows of {column: float} (empty cells left out)."""
        import csv

        path = self.path / METRICS_CSV
        if not path.is_file():
            return []
        with open(path, newline="") as f:
            return [{k: float(v) for k, v in row.items() if v not in ("", None)} for row in csv.DictReader(f)]


def load_run(path: Path | str) -> Run:
    """The run in `path` (a run folder); FileNotFoundError names a missing folder or record."""
    folder = RunFolder(path)  # names a missing folder
    if not (folder.path / RUN_JSON).is_file():
        raise FileNotFoundError(f"{folder.path} is not a run folder: it has no {RUN_JSON}")
    return Run(folder.path, folder.read())


def find_runs(root: Path | str) -> list[Run]:
    """Every run under `root` (or `root` itself when it is a run folder), oldest first."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"no such folder: {root}")
    paths = [root] if (root / RUN_JSON).is_file() else sorted(p.parent for p in root.rglob(RUN_JSON))
    runs = [Run(p, RunFolder(p).read()) for p in paths]
    return sorted(runs, key=lambda r: (str(r.record.get("start") or ""), str(r.path)))


def matches(run: Run, filters: list[str]) -> bool:
    """`key=value` filters (all must hold; values compared as text, `true`/`false`/`null` as YAML writes them)."""
    for f in filters:
        key, sep, want = f.partition("=")
        if not sep:
            raise ValueError(f"a filter is KEY=VALUE (e.g. experiment=samp_n100 status=completed), got {f!r}")
        value = run.get(key)
        text = "null" if value is None else str(value).lower() if isinstance(value, bool) else str(value)
        if text != want:
            return False
    return True


def varying_keys(runs: list[Run], keys: list[str]) -> list[str]:
    """The `keys` whose values differ between `runs`, less those that only name each run's own folder
    (checkpoint and log paths, its overrides) and its timing."""
    def own(run: Run, key: str) -> bool:
        return str(run.path) in json.dumps(run.values.get(key), default=str)

    noise = ("start", "end", "pid", "fit_time_s", "host", "overrides")
    return [k for k in keys if k not in noise and len({json.dumps(r.values.get(k), default=str) for r in runs}) > 1
            and not all(own(r, k) for r in runs)]


def check_key(runs: list[Run], key: str, what: str = "key") -> None:
    """ValueError naming the keys that exist when no run has `key`."""
    if any(r.has(key) for r in runs):
        return
    keys = sorted(set().union(*(r.values for r in runs))) if runs else []
    varying = varying_keys(runs, keys)
    metrics = sorted(set().union(*(r.metrics for r in runs))) if runs else []
    raise ValueError(f"unknown {what} {key!r}: no run here has it. Keys that vary between these runs: "
                     f"{', '.join(varying) or 'none'}. Metrics: {', '.join(metrics) or 'none'}. "
                     f"Every other key: {', '.join(k for k in keys if k not in varying)}")
