"""The paper's metrics (docs/design.md section 4) from per-problem records, and their markdown table.

A record is one problem's outcome (JSON-ready, `samp.eval.harness`): `reached` per position tolerance
(final end-effector position error below it and orientation error below the orientation tolerance), the
violations found by `samp.eval.checks`, the end-effector path length, the solution time and the per-step
inference times.

  success rate   reached and no violation (collision, self-collision, joint limits), per tolerance
  reach rate     reached, whatever happened on the way
  collision rate penetration of an obstacle at a step or sub-step; self-collision and joint-limit rates
                 apart, and `violation_rate` for any of the three
  path length    sum of ||dp_ee|| over the executed waypoints, metres: mean and std over the successful
                 problems (a failed path's length says little), and over all problems as `path_length_all`
  solution time  wall time spent producing each trajectory (seconds): `solution_time_b1` one problem at a
                 time (B = 1; the paper's), over the `timed_problems` solved so; `solution_time` in the
                 batched rollouts the outcomes come from (a batch's latency)
  step time      wall time per policy step call: `step_time_b1` at B = 1, `inference_time` batched
  throughput     problems per second in the batched rollouts (B = the rollout's batch_size)

`METRICS` below is the one place a metric is defined; everything else reads it: `summarize`
(metrics.json), `markdown_table` (metrics.md), `EvalCallback` (`logged_metrics()`), the values flattened
into run.json after training (`flat_metrics()`), and the plots and paper tables of `samp.runs`
(`metric(name).key`, `metric_keys(...)`).

To add a metric, add one `Metric` to `METRICS` (its place there is its keys' place in metrics.json) and
change nothing else. Say how a problem's value is read from its record (`value`), how values pool
(`stats`), over which problems (`over`), and where it shows: a `column` of the table (placed by its
`rank`), `logged` during training, `flat` in run.json, a `curve` panel. A value the rollout does not
record yet goes into the record first (`samp.eval.harness`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from samp.eval.config import RolloutConfig, tolerance_label

__all__ = ["METRICS", "STATS", "TABLE_COLUMNS", "Column", "Metric", "flat_metrics", "logged_metrics", "markdown_table",
           "metric", "metric_keys", "reached_within", "summarize", "table_metrics", "wilson_interval"]


def reached_within(position_error: float | None, orientation_error: float | None, cfg: RolloutConfig) -> dict[str, bool]:
    """{"2cm": bool, "1cm": bool, ...}: the final pose within each position tolerance and the orientation one."""
    if position_error is None or orientation_error is None:
        return {tolerance_label(t): False for t in cfg.tolerances()}
    ok = orientation_error < cfg.orientation_tolerance
    return {tolerance_label(t): bool(ok and position_error < t) for t in cfg.tolerances()}


# ----------------------------------------------------------------- how a metric's values pool
Z95 = 1.959963984540054  # the standard normal's 97.5 % quantile: two-sided 95 % intervals


def wilson_interval(successes: int, n: int, z: float = Z95) -> tuple[float | None, float | None]:
    """The Wilson score interval of a binomial rate (successes of n), in [0, 1]; (None, None) for n = 0.
    Unlike p ± z sqrt(p(1-p)/n) it stays within [0, 1] and does not collapse at 0 or n successes. scipy
    computes it (`binomtest(...).proportion_ci(method="wilson")`, no continuity correction); `z` is turned
    into its two-sided confidence level."""
    if n == 0:
        return None, None
    from scipy.stats import binomtest, norm

    level = 2 * float(norm.cdf(z)) - 1
    ci = binomtest(int(successes), int(n)).proportion_ci(confidence_level=level, method="wilson")
    return float(ci.low), float(ci.high)


def _rate(values: list) -> tuple:
    """The fraction of true values, in [0, 1], and its Wilson 95 % interval (low, high)."""
    if not values:
        return None, None, None
    hits = sum(bool(v) for v in values)
    return (hits / len(values), *wilson_interval(hits, len(values)))


def _mean_std(values: list) -> tuple:
    """Mean and numpy's population std; None for no values."""
    if not values:
        return None, None
    arr = np.asarray(values, dtype=np.float64)
    return float(arr.mean()), float(arr.std())


def _counts(values: list) -> tuple:
    """{value: how many problems}, in order of first appearance."""
    counts: dict = {}
    for v in values:
        counts[v] = counts.get(v, 0) + 1
    return (counts,)


def _throughput(values: list) -> tuple:
    """(batch, seconds the batch took) per problem -> problems per second; a problem answered alone
    (batch None) is a batch of its own."""
    times = {(i, None) if batch is None else batch: seconds for i, (batch, seconds) in enumerate(values)
             if seconds is not None}
    total = sum(times.values())
    return (len(values) / total if values and total > 0 else None,)


# stats -> (key suffixes, pooling function returning one value per suffix); the first suffix is the headline
STATS: dict[str, tuple[tuple[str, ...], Callable[[list], tuple]]] = {
    "rate": (("", "_ci_low", "_ci_high"), _rate),
    "mean_std": (("_mean", "_std"), _mean_std),
    "mean": (("_mean",), lambda values: _mean_std(values)[:1]),
    "mean_max": (("_mean", "_max"), lambda values: (_mean_std(values)[0], max(values) if values else None)),
    "counts": (("",), _counts),
    "count": (("",), lambda values: (sum(bool(v) for v in values),)),
    "throughput": (("",), _throughput),
}


# ----------------------------------------------------------------- what a problem's record says
def violated(record: dict, tol: str) -> bool:
    """Any physical violation: a collision, a self-collision or a joint limit."""
    return bool(record["collision"] or record["self_collision"] or record["joint_limit_violation"])


def reached(record: dict, tol: str) -> bool:
    return bool(record["reached"][tol])


def succeeded(record: dict, tol: str) -> bool:
    """Reached within the tolerance labelled `tol`, with no violation."""
    return reached(record, tol) and not violated(record, tol)


def collided(record: dict, tol: str) -> bool:
    return bool(record["collision"])


def recorded(key: str) -> Callable[[dict, str], Any]:
    """The record's own value at `key` (None when an older record lacks it)."""
    return lambda record, tol: record.get(key)


def timed_alone(record: dict, tol: str) -> bool:
    """Whether the problem was also solved one at a time (B = 1) for its latency."""
    return record.get("solution_time_b1") is not None


# ----------------------------------------------------------------- the registry
_SCALE = {"%": 100.0, "ms": 1e3}  # values are fractions, seconds and metres; a column's unit scales them


@dataclass(frozen=True)
class Column:
    """A column of `markdown_table`: "title [unit]" ("title@2cm [unit]" per tolerance), the value scaled to
    the unit (% of a fraction, ms of seconds) with `digits` decimals, "mean ± std" for a mean_std metric.
    Columns sort by `rank`, after planner, split and problems."""

    title: str
    unit: str
    digits: int
    rank: int

    def header(self, label: str | None = None) -> str:
        return f"{self.title}{'' if label is None else '@' + label} [{self.unit}]"

    def cell(self, values: list) -> str:
        """`values`: the metric's values under its keys (rate: value, interval low and high, shown as
        "93.3 [84.1, 97.4]"; mean_std: mean and std, shown as "1.24 ± 0.53")."""
        if values[0] is None:
            return "-"
        text = [f"{v * _SCALE.get(self.unit, 1.0):.{self.digits}f}" for v in values if v is not None]
        if len(values) == 3:  # a rate and its interval
            return f"{text[0]} [{text[1]}, {text[2]}]" if len(text) == 3 else text[0]
        return " ± ".join(text)


@dataclass(frozen=True)
class Metric:
    """One metric: its name, a problem's value, how the values pool and where the metric shows.

    Its keys in metrics.json are `name` + the suffixes of its `stats` (`STATS`): `collision_rate`;
    `path_length_mean`, `path_length_std`; a per-tolerance metric also has them at every tolerance
    (`success_rate@2cm`, `success_rate@1cm`), the bare ones being the stopping tolerance's. The first key
    (`key`) is the one logged, flattened and plotted.

    Args:
        name: e.g. "collision_rate", "path_length".
        value: (record, tolerance label) -> the problem's value; None leaves the problem out (of a rate:
            counts as false). The label is the stopping tolerance's unless the metric is per tolerance.
        stats: how the values pool, a key of `STATS`: "rate", "mean_std", "mean", "mean_max", "counts".
        over: (record, tolerance label) -> whether the problem counts (e.g. `succeeded`); None: all do.
        per_step: `value` gives a list per problem (one entry per policy step), pooled over every step.
        per_tolerance: reported at every position tolerance (`RolloutConfig.tolerances()`).
        column: its column in `markdown_table`, or None.
        logged: logged as `eval/<key>` during training (`EvalCallback`).
        flat: flattened into run.json after training (`eval/<planner>/<split>/<key>`); rates are also
            plotted per planner on the run's summary page (`samp.runs.plots`).
        curve: a panel of the learning-curve figure (`samp.runs.plots.CURVE_METRICS`).
    """

    name: str
    value: Callable[[dict, str], Any]
    stats: str
    over: Callable[[dict, str], bool] | None = None
    per_step: bool = False
    per_tolerance: bool = False
    column: Column | None = None
    logged: bool = False
    flat: bool = False
    curve: bool = False

    def __post_init__(self):
        if self.stats not in STATS:
            raise ValueError(f"metric {self.name!r}: stats must be one of {sorted(STATS)}, got {self.stats!r}")
        if self.column is not None and self.stats not in ("rate", "mean_std", "throughput"):
            raise ValueError(f"metric {self.name!r}: a table column shows a rate, a mean_std or a throughput, got "
                             f"{self.stats!r}")
        if self.curve and not self.logged:
            raise ValueError(f"metric {self.name!r}: a learning curve plots a logged metric; set logged=True")

    def keys(self, label: str | None = None) -> list[str]:
        """Its keys in metrics.json, at the tolerance `label` ("2cm") or bare."""
        return [self.name + suffix + ("" if label is None else "@" + label) for suffix in STATS[self.stats][0]]

    @property
    def key(self) -> str:
        """The headline key: `name` for a rate, `name_mean` for a mean."""
        return self.keys()[0]

    def pool(self, records: list[dict], tol: str) -> tuple:
        """Its values over `records` at the tolerance labelled `tol`, one per key."""
        values = [self.value(r, tol) for r in records if self.over is None or self.over(r, tol)]
        if self.per_step:
            values = [v for per_problem in values for v in per_problem]
        if self.stats != "rate":
            values = [v for v in values if v is not None]
        return STATS[self.stats][1](values)


METRICS: tuple[Metric, ...] = (
    Metric("success_rate", succeeded, "rate", per_tolerance=True, column=Column("success", "%", digits=1, rank=30),
           logged=True, flat=True, curve=True),
    Metric("reach_rate", reached, "rate", per_tolerance=True, column=Column("reach", "%", digits=1, rank=40),
           logged=True, flat=True, curve=True),
    Metric("collision_rate", recorded("collision"), "rate", column=Column("collision", "%", digits=1, rank=50),
           logged=True, flat=True),
    Metric("self_collision_rate", recorded("self_collision"), "rate",
           column=Column("self-coll.", "%", digits=1, rank=60), logged=True),
    Metric("joint_limit_rate", recorded("joint_limit_violation"), "rate",
           column=Column("joint limits", "%", digits=1, rank=70), logged=True),
    Metric("violation_rate", violated, "rate"),
    Metric("path_length", recorded("path_length"), "mean_std", over=succeeded,
           column=Column("path length", "m", digits=2, rank=20), logged=True, flat=True),
    Metric("path_length_all", recorded("path_length"), "mean_std"),
    # Batched rollouts: the wall time of the calls a problem took part in (the batch's), per step call.
    Metric("solution_time", recorded("solution_time"), "mean_std", logged=True),
    Metric("inference_time", recorded("step_times"), "mean_std", per_step=True, logged=True),
    # One problem at a time (B = 1), the paper's solution and step times, over the problems timed so.
    Metric("solution_time_b1", recorded("solution_time_b1"), "mean_std", over=timed_alone,
           column=Column("soln. time B=1", "s", digits=3, rank=10), flat=True),
    Metric("step_time_b1", lambda record, tol: record.get("step_times_b1") or [], "mean_std", per_step=True,
           over=timed_alone, column=Column("step B=1", "ms", digits=2, rank=80), flat=True),
    Metric("timed_problems", timed_alone, "count"),
    Metric("throughput", lambda record, tol: (record.get("batch"), record.get("batch_time")), "throughput",
           column=Column("batched", "problems/s", digits=1, rank=90), flat=True),
    Metric("steps", recorded("steps"), "mean", logged=True),
    Metric("collision_depth", recorded("collision_depth"), "mean_max", over=collided),
    Metric("terminations", recorded("termination"), "counts"),
)


def metric(name: str) -> Metric:
    """The registered metric `name`; ValueError naming the registered ones."""
    for m in METRICS:
        if m.name == name:
            return m
    raise ValueError(f"no metric {name!r}; registered: {', '.join(m.name for m in METRICS)}")


def metric_keys(*, logged: bool = False, flat: bool = False, curve: bool = False, rate: bool = False) -> tuple[str, ...]:
    """The headline keys of the metrics that have every property asked for, in `METRICS` order;
    e.g. `metric_keys(flat=True, rate=True)`: the rates flattened into run.json."""
    return tuple(m.key for m in METRICS if (m.logged or not logged) and (m.flat or not flat)
                 and (m.curve or not curve) and (m.stats == "rate" or not rate))


def logged_metrics() -> tuple[str, ...]:
    """Logged as `eval/<key>` and `eval/<split>/<key>` by `EvalCallback` during training."""
    return metric_keys(logged=True)


def flat_metrics() -> tuple[str, ...]:
    """Flattened into run.json after training, as `eval/<planner>/<split>/<key>`."""
    return metric_keys(flat=True)


def table_metrics() -> tuple[Metric, ...]:
    """The metrics with a column in `markdown_table`, left to right."""
    return tuple(sorted((m for m in METRICS if m.column is not None), key=lambda m: m.column.rank))


def _check_registry() -> None:
    keys = [k for m in METRICS for k in m.keys()]
    if len(set(keys)) != len(keys) or len({m.name for m in METRICS}) != len(METRICS):
        raise ValueError(f"metric names and keys must be unique, got {keys}")
    ranks = [m.column.rank for m in table_metrics()]
    if len(set(ranks)) != len(ranks):
        raise ValueError(f"table column ranks must be unique, got {ranks}")


_check_registry()


# ----------------------------------------------------------------- metrics.json and metrics.md
def summarize(records: list[dict], cfg: RolloutConfig) -> dict:
    """The metrics of `records` (one problem each); rates are fractions in [0, 1].

    Keys in order: "problems"; the per-tolerance metrics tolerance by tolerance (`success_rate@2cm`,
    `reach_rate@2cm`, `success_rate@1cm`, ...); the same at the stopping tolerance without the suffix;
    every other metric in `METRICS` order."""
    if not records:
        return {"problems": 0}
    primary = tolerance_label(cfg.position_tolerance)
    per_tolerance = [m for m in METRICS if m.per_tolerance]
    out: dict = {"problems": len(records)}
    for label in (tolerance_label(t) for t in cfg.tolerances()):
        for m in per_tolerance:
            out.update(zip(m.keys(label), m.pool(records, label)))
    for m in per_tolerance:
        out.update({bare: out[at] for bare, at in zip(m.keys(), m.keys(primary))})
    for m in METRICS:
        if not m.per_tolerance:
            out.update(zip(m.keys(), m.pool(records, primary)))
    return out


TABLE_COLUMNS = ["planner", "group", "problems", *(m.column.header() for m in table_metrics())]


def markdown_table(rows: list[tuple[str, str, dict]], cfg: RolloutConfig) -> str:
    """(planner, group, metrics) rows -> a markdown table in the paper's Table I/II style; per-tolerance
    metrics (success, reach) are given at every tolerance, the stopping tolerance first."""
    labels = [tolerance_label(t) for t in cfg.tolerances()]
    columns = [(m.column, label, m.keys(label)) for m in table_metrics()
               for label in (labels if m.per_tolerance else [None])]
    header = TABLE_COLUMNS[:3] + [column.header(label) for column, label, _ in columns]
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for planner, split, m in rows:
        cells = [planner, split, str(m.get("problems", 0)), *(c.cell([m.get(k) for k in keys]) for c, _, keys in columns)]
        lines.append("| " + " | ".join(cells) + " |")
    note = (f"Reached: end-effector within {labels[0]} and {cfg.orientation_tolerance:g} deg at the end of the rollout "
            f"(which stops at {labels[0]}); success: reached with no collision, self-collision or joint-limit violation. "
            "Rates: percent [Wilson 95 % interval]. Path length: mean ± std over successful problems. Solution and "
            "step time: one problem at a time (B = 1), over the problems timed so; batched: problems per second "
            "in the batched rollouts the outcomes come from.")
    return "\n".join(lines) + "\n\n" + note + "\n"
