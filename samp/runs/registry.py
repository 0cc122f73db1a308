"""The run registry: every folder with a run.json under a root, read into `Run`s that answer any key.

A run's keys are one flat namespace: its resolved config as dotted keys (`datamodule.n_e`, `name`,
`system.collision_loss`), its record (`status`, `experiment`, `seed`, `dataset_id`, `fit_time_s`,
`code_version.git_commit`, `sweep.member`, ...), the protocol of its evaluation (`protocol`: 2, 1 or
null; `samp.runs.protocol`) and its final metrics (`val/loss`, `eval/samp/benchmark/success_rate`, ...).
`--by`, filters and table columns all use these keys.
"""

from __future__ import annotations

import difflib
import json
import platform
from dataclasses import dataclass, field
from datetime import datetime
from functools import cached_property
from pathlib import Path

from samp.provenance import process_gone
from samp.names import TRACKING_ARTIFACTS_DIR
from samp.runs.folder import METRICS_CSV, RUN_JSON, RunFolder
from samp.runs.lineage import flatten
from samp.runs.protocol import BLOCKS, PROTOCOL, eval_key, interval_keys, is_rate, protocol_of

__all__ = ["DIED", "EVAL_METRICS", "Run", "check_key", "find_runs", "load_run", "matches", "over_problems",
           "scan_runs", "varying_keys"]

EVAL_METRICS = Path("eval") / "metrics.json"  # written by `python -m samp.eval` (samp.eval.names)
EVAL_PROBLEMS = Path("eval") / "problems.jsonl"  # its per-problem records, beside it
DIED = "died"  # shown for a run recorded running whose process is gone (`Run.status`)
HIDDEN = ("config", "metrics", "packages", "traceback", "command", "starts", "loggers", "files_sha256")  # not keys of their own


@dataclass
class Run:
    """One run folder, read once."""

    path: Path
    record: dict = field(repr=False)

    @cached_property
    def values(self) -> dict:
        """Config and record as dotted keys (the record wins where both have a key, e.g. `seed`), and the
        evaluation's `protocol`."""
        record = {k: v for k, v in self.record.items() if k not in HIDDEN}
        return {**flatten(self.record.get("config") or {}), **flatten(record), PROTOCOL: self.protocol,
                "status": self.status}

    @cached_property
    def metrics(self) -> dict:
        """run.json's metrics, with those of the run's evaluation (eval/metrics.json, protocol 2) over them: a
        later `python -m samp.eval run=RUN overwrite=true` (another benchmark, samp+check) replaces that file,
        and tables then show what it measured."""
        metrics = dict(self.record.get("metrics") or {})
        report = self.evaluation
        if report and int(report.get(PROTOCOL, 1)) >= 2 and report.get("planner"):
            from samp.eval.report import flat_report

            metrics.update(flat_report(report, report["planner"]))
        return metrics

    @property
    def name(self) -> str:
        """`<parent>/<folder>` (an experiment and timestamp, or a sweep and member)."""
        return f"{self.path.parent.name}/{self.path.name}"

    @cached_property
    def status(self) -> str:
        """The record's status, except `died` for a run recorded `running` whose process is gone: run.json
        names the host and process id that trains it, and a process killed outright (SIGKILL, the OOM killer)
        never writes its end. A run of another host cannot be asked and stays `running`."""
        status = self.record.get("status", "?")
        pid, host = self.record.get("pid"), self.record.get("host")
        if status != "running" or not isinstance(pid, int) or host != platform.node():
            return status
        starts = self.record.get("starts") or [self.record.get("start")]
        try:
            started = datetime.fromisoformat(str(starts[-1])).timestamp()
        except (TypeError, ValueError):
            started = None
        return DIED if process_gone(pid, started) else status

    @property
    def robot(self) -> str | None:
        return self.values.get("robot.name") or self.values.get("system.robot")

    def get(self, key: str):
        """A metric, a config key or a record key; None when the run has no such key."""
        return self.metrics[key] if key in self.metrics else self.values.get(key)

    def setting(self, key: str):
        """What runs are grouped by (`by=`): the config or record value of `key`, a metric only when no config
        or record key has that name (a config group `loss` and Lightning's `loss` metric share one)."""
        return self.values[key] if key in self.values else self.metrics.get(key)

    def has(self, key: str) -> bool:
        return key in self.metrics or key in self.values

    @cached_property
    def evaluation(self) -> dict | None:
        """The run's eval/metrics.json (per split, the planner's and the expert's metrics), if any."""
        path = self.path / EVAL_METRICS
        return json.loads(path.read_text()) if path.is_file() else None

    @cached_property
    def protocol(self) -> int | None:
        """The protocol its evaluation followed (`samp.runs.protocol`): 2, 1 (an older evaluation) or None."""
        return protocol_of(self.evaluation, self.metrics)

    def interval(self, key: str) -> tuple[float, float] | None:
        """The Wilson 95 % interval the run recorded beside the rate `key` (`<key>_ci_low`, `<key>_ci_high`)."""
        low, high = (self.metrics.get(k) for k in interval_keys(key))
        return None if low is None or high is None else (float(low), float(high))

    def problems(self, key: str) -> int | None:
        """How many problems the metric `key` (`eval/<planner>/<group>/<metric>`) is over, as eval/metrics.json
        says (the group's summary, else its "groups" or protocol 1's "problems" entry); None when unknown."""
        parts, report = eval_key(key), self.evaluation or {}
        if parts is None:
            return None
        planner, group, _ = parts
        block = "metrics" if planner == report.get("planner") else BLOCKS.get(planner)
        listed = report.get("problems") if isinstance(report.get("problems"), dict) else {}
        counts = (((report.get(block) or {}).get(group) or {}).get("problems") if block else None,
                  ((report.get("groups") or {}).get(group) or {}).get("problems"), listed.get(group))
        return next((int(n) for n in counts if isinstance(n, int) and not isinstance(n, bool)), None)

    @cached_property
    def _problem_records(self) -> list[dict]:
        """eval/problems.jsonl, without the bulky per-step fields; empty when the run has none."""
        path = self.path / EVAL_PROBLEMS
        if not path.is_file():
            return []
        bulky = ("trajectory", "step_times", "step_times_b1", "q_start", "q_goal", "first_collision_state")
        with open(path) as f:
            return [{k: v for k, v in json.loads(line).items() if k not in bulky} for line in f if line.strip()]

    def outcomes(self, key: str) -> dict[str, float] | None:
        """Per problem (by its id), the 0/1 outcome behind the rate `key` (`eval/<planner>/<group>/<rate>`), from
        eval/problems.jsonl; None when the run's records cannot say (no such file, a group they do not list:
        evaluations before the records named their groups knew only the sections)."""
        from samp.eval.config import tolerance_label
        from samp.eval.metrics import metric

        parts, report = eval_key(key), self.evaluation or {}
        if parts is None or not is_rate(key) or not self._problem_records:
            return None
        planner, group, name = parts
        rate, _, tol = name.partition("@")
        tol = tol or tolerance_label(float((report.get("config") or {}).get("position_tolerance", 0.02)))
        m = metric(rate)
        out = {}
        for r in self._problem_records:
            groups = r.get("groups") or [r.get("group")]
            if r.get("planner") == planner and group in groups:
                out[str(r.get("problem"))] = float(bool(m.value(r, tol)))
        return out or None

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


def scan_runs(root: Path | str) -> tuple[list[Run], list[tuple[Path, str]]]:
    """(every intact run under `root` (or `root` itself when it is a run folder), oldest first; every
    damaged record as (run.json path, what is wrong)). One bad run.json never hides the others."""
    root = Path(root)
    if not root.is_dir():
        raise FileNotFoundError(f"no such folder: {root}")
    # a hidden folder is not a published run (`.pull-*` is a pull in progress, samp/runs/sharing.py), and a local
    # MLflow store's artifacts hold copies of run.json that are not runs of their own
    paths = [root] if (root / RUN_JSON).is_file() else sorted(
        p.parent for p in root.rglob(RUN_JSON)
        if not any(s.startswith(".") or s == TRACKING_ARTIFACTS_DIR for s in p.relative_to(root).parts[:-1]))
    runs, damaged = [], []
    for p in paths:
        try:
            runs.append(Run(p, RunFolder(p).read()))
        except (ValueError, OSError) as err:  # DamagedRecord, or a file that cannot be read
            damaged.append((p / RUN_JSON, str(err)))
    return sorted(runs, key=lambda r: (str(r.record.get("start") or ""), str(r.path))), damaged


def find_runs(root: Path | str) -> list[Run]:
    """Every intact run under `root` (or `root` itself when it is a run folder), oldest first; damaged
    records are left out (`scan_runs` names them)."""
    return scan_runs(root)[0]


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


def over_problems(runs: list[Run], key: str) -> tuple[float, float] | None:
    """The 95 % interval of the rate `key` over several runs (mean over runs), resampling the problems they were
    evaluated on (`samp.runs.intervals`); one run: the Wilson interval it recorded. None when a run's records
    cannot give its per-problem outcomes, or `key` is not a rate."""
    from samp.runs.intervals import problem_bootstrap

    if not runs or not is_rate(key):
        return None
    if len(runs) == 1:
        return runs[0].interval(key)
    outcomes = [r.outcomes(key) for r in runs]
    return None if any(o is None for o in outcomes) else problem_bootstrap(outcomes)


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
    close = difflib.get_close_matches(key, keys + metrics, n=1)
    raise ValueError(f"unknown {what} {key!r}: no run here has it{f' (did you mean {close[0]!r}?)' if close else ''}. "
                     "Keys that vary between these runs: "
                     f"{', '.join(varying) or 'none'}. Metrics: {', '.join(metrics) or 'none'}. "
                     f"Every other key: {', '.join(k for k in keys if k not in varying)}")
