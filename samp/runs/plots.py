"""Plots over runs as PNG (matplotlib, no display needed):

- learning curves: a metric from each run's metrics.csv against the epoch, one line per value of a key
  (the mean over the runs sharing it), as the paper's figure of success and reach rate per anchor size;
- bars: final metrics (run.json) per value of a key, across a sweep: the mean over the runs, its error bar
  the 95 % interval over the problems they were evaluated on (a bootstrap, `samp.runs.intervals`) where
  their records give it (rates of an evaluation), else the min and max over the runs;
- a run's summary page: its losses, and its rates per planner and group of problems with their Wilson
  95 % intervals.
"""

from __future__ import annotations

import math
from pathlib import Path

from samp.eval.metrics import metric_keys, wilson_interval
from samp.names import EVAL_PREFIX
from samp.runs.protocol import BENCHMARK, GROUPS, HARD_BENCHMARK, hard, interval_keys, is_rate, label
from samp.runs.registry import Run, check_key, over_problems
from samp.runs.tables import fmt

__all__ = ["CURVE_METRICS", "RATES", "plot_bars", "plot_curves", "plot_run_summary"]

# EvalCallback's values over all its problems (samp.eval.callback), the figure's panels: the metrics marked
# `curve` in samp.eval.metrics.METRICS (success and reach rate).
CURVE_METRICS = tuple(EVAL_PREFIX + key for key in metric_keys(curve=True))


def _groups(runs: list[Run], by: str) -> dict:
    check_key(runs, by, "--by key")
    groups: dict = {}
    for r in runs:
        groups.setdefault(r.setting(by), []).append(r)
    numeric = all(isinstance(k, (int, float)) for k in groups)
    return dict(sorted(groups.items(), key=lambda kv: kv[0] if numeric else str(kv[0])))


def _figure(n: int):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, n, figsize=(5.0 * n, 3.8), squeeze=False)
    return plt, fig, axes[0]


def _curve(runs: list[Run], metric: str, x: str) -> tuple[list[float], list[float]]:
    """The mean of `metric` over `runs` at each value of `x` (epoch or step) where any run logged it."""
    by_x: dict[float, list[float]] = {}
    for r in runs:
        for row in r.curves():
            if metric in row and x in row:
                by_x.setdefault(row[x], []).append(row[metric])
    xs = sorted(by_x)
    return xs, [sum(by_x[v]) / len(by_x[v]) for v in xs]


def plot_curves(runs: list[Run], by: str, metrics: list[str], out: Path, x: str = "epoch") -> Path:
    """One panel per metric, one line per value of `by`; ValueError when no run logged a metric."""
    groups = _groups(runs, by)
    plt, fig, axes = _figure(len(metrics))
    for ax, metric in zip(axes, metrics):
        drawn = 0
        for value, members in groups.items():
            xs, ys = _curve(members, metric, x)
            if xs:
                ax.plot([v + 1 for v in xs] if x == "epoch" else xs, ys, marker="o", ms=3, label=f"{by}={fmt(value)}")
                drawn += 1
        if not drawn:
            plt.close(fig)
            logged = sorted(set().union(*(set(row) for r in runs for row in r.curves())) - {"epoch", "step"})
            raise ValueError(f"no run logged {metric!r} in its metrics.csv; logged there: {', '.join(logged) or 'nothing'}")
        ax.set_xlabel(x)
        ax.set_ylabel(metric)
        ax.set_title(metric)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    return save_figure(plt, fig, out)


def _errors(value: float, low: float, high: float) -> tuple[float, float]:
    """Error bar lengths below and above `value` for the range [low, high] (never negative: a percentile
    interval need not be centred on the mean)."""
    return max(0.0, value - low), max(0.0, high - value)


def plot_bars(runs: list[Run], by: str, metrics: list[str], out: Path) -> Path:
    """One panel per metric: a bar per value of `by`, the mean over its runs. Error bars: the 95 %
    interval over its runs' problems (`samp.runs.intervals`) when every bar has one (a rate, in percent), else the min
    and max over its runs; the y label says which."""
    groups = _groups(runs, by)
    for m in metrics:
        check_key(runs, m, "metric")
    plt, fig, axes = _figure(len(metrics))
    labels = [fmt(v) for v in groups]
    for ax, metric in zip(axes, metrics):
        intervals = [over_problems(members, metric) for members in groups.values()]
        wilson = any(intervals) and all(i is not None for i, members in zip(intervals, groups.values())
                                        if any(r.has(metric) for r in members))
        scale = 100.0 if is_rate(metric) else 1.0
        means, errors = [], []
        for members, interval in zip(groups.values(), intervals):
            vals = [float(r.get(metric)) for r in members if isinstance(r.get(metric), (int, float))]
            mean = sum(vals) / len(vals) if vals else math.nan
            means.append(scale * mean)
            span = interval if wilson else (min(vals), max(vals)) if vals else (mean, mean)
            errors.append(_errors(scale * mean, scale * span[0], scale * span[1]) if vals else (math.nan, math.nan))
        ax.bar(labels, means, yerr=list(zip(*errors)), capsize=3, color="tab:blue", alpha=0.8)
        ax.set_xlabel(by)
        if sum(map(len, labels)) > 6 * len(labels):  # names rather than numbers: slanted, so they do not overlap
            ax.tick_params(axis="x", labelrotation=30)
            plt.setp(ax.get_xticklabels(), ha="right", rotation_mode="anchor")
        unit = " [%]" if scale == 100.0 else ""
        ax.set_ylabel(f"mean of runs{unit}; bars: " + ("95 % over problems" if wilson else "min to max"))
        ax.set_title(metric)
        ax.grid(axis="y", alpha=0.3)
    return save_figure(plt, fig, out)


# A panel per rate flattened into run.json after training (samp.eval.metrics.METRICS): success, reach, collision.
RATES = metric_keys(flat=True, rate=True)


def _summary_groups(protocol: int | None, planners: list[tuple[str, dict]]) -> list[str]:
    """The groups of problems a summary shows, those the evaluation has: protocol 2's val, train and
    benchmark scenes, the benchmark's hard subset and the hard benchmark; protocol 1's train and held-out scenes."""
    wanted = (*GROUPS[2][:3], hard(BENCHMARK), *GROUPS[2][3:]) if protocol == 2 else GROUPS[1]
    return [g for g in wanted if any(g in m for _, m in planners)]


def _rate_bar(summary: dict, rate: str) -> tuple[float, tuple[float, float]]:
    """A rate in percent and its error bar lengths: its Wilson 95 % interval as recorded (`<rate>_ci_low`,
    `_ci_high`), or from the group's problem count (an evaluation that recorded none); NaN (nothing drawn)
    where there is no rate or no interval."""
    value = summary.get(rate)
    if value is None:
        return math.nan, (math.nan, math.nan)
    low, high = (summary.get(k) for k in interval_keys(rate))
    if (low is None or high is None) and summary.get("problems"):
        low, high = wilson_interval(round(value * summary["problems"]), summary["problems"])
    if low is None or high is None:
        return 100 * value, (math.nan, math.nan)
    return 100 * value, _errors(100 * value, 100 * low, 100 * high)


def plot_run_summary(run: Run, out: Path) -> Path:
    """One policy run on one page: its train and val losses per step (metrics.csv) and, when it was
    evaluated, success, reach and collision rate per planner and group of problems (eval/metrics.json),
    with their Wilson 95 % intervals as error bars."""
    evaluated = run.evaluation or {}
    planners = [(name, evaluated[key]) for name, key in (("policy", "metrics"), ("expert", "expert"),
                                                          ("straight", "straight")) if evaluated.get(key)]
    plt, fig, axes = _figure(1 + len(RATES) * bool(planners))
    rows = run.curves()
    for metric, style in (("train/loss", "-"), ("val/loss", "o-")):
        pts = [(row["step"], row[metric]) for row in rows if metric in row and "step" in row]
        if pts:
            axes[0].plot(*zip(*pts), style, ms=3, label=metric)
    axes[0].set_yscale("log")
    axes[0].set(xlabel="step", title="losses")
    axes[0].grid(alpha=0.3)
    if axes[0].get_legend_handles_labels()[0]:  # a run without metrics.csv has no losses to name
        axes[0].legend(fontsize=8)
    groups = _summary_groups(run.protocol, planners)
    for ax, rate in zip(axes[1:], RATES):
        for i, (name, metrics) in enumerate(planners):
            xs = [j + (i - (len(planners) - 1) / 2) * 0.25 for j in range(len(groups))]
            values, errors = zip(*(_rate_bar(metrics.get(g) or {}, rate) for g in groups)) if groups else ((), ())
            ax.bar(xs, values, width=0.25, yerr=list(zip(*errors)) or None, capsize=2, label=name)
        ax.set_xticks(range(len(groups)), [g.replace("_", " ") if g.startswith((BENCHMARK, HARD_BENCHMARK))
                                           else f"{g} scenes"
                                           for g in groups])
        ax.set(title=rate.replace("_", " ") + " [%]", ylabel="error bars: Wilson 95 %", ylim=(0, 119))
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=7, ncol=len(planners), loc="upper center")
    protocol = "" if run.protocol is None else f"  (protocol {label(run.protocol, short=True)})"
    fig.suptitle(f"{run.get('experiment')}  {run.path.name}{protocol}", fontsize=9)
    return save_figure(plt, fig, out)


def save_figure(plt, fig, out: Path, dpi: int = 120) -> Path:
    """Lay `fig` out, write it to `out` (its folder made if needed) and close it."""
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=dpi)
    plt.close(fig)
    return out
