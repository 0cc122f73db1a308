"""Plots over runs as PNG (matplotlib, no display needed):

- learning curves: a metric from each run's metrics.csv against the epoch, one line per value of a key
  (the mean over the runs sharing it), as the paper's figure of success and reach rate per anchor size;
- bars: final metrics (run.json) per value of a key, across a sweep (mean, with the std as error bar).
"""

from __future__ import annotations

from pathlib import Path

from samp.eval.metrics import metric_keys
from samp.names import EVAL_PREFIX
from samp.runs.registry import Run, check_key
from samp.runs.tables import fmt

__all__ = ["CURVE_METRICS", "RATES", "plot_bars", "plot_curves", "plot_run_summary"]

# EvalCallback's values over all its problems (samp.eval.callback), the figure's panels: the metrics marked
# `curve` in samp.eval.metrics.METRICS (success and reach rate).
CURVE_METRICS = tuple(EVAL_PREFIX + key for key in metric_keys(curve=True))


def _groups(runs: list[Run], by: str) -> dict:
    check_key(runs, by, "--by key")
    groups: dict = {}
    for r in runs:
        groups.setdefault(r.get(by), []).append(r)
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
    return _save(plt, fig, out)


def plot_bars(runs: list[Run], by: str, metrics: list[str], out: Path) -> Path:
    """One panel per metric: a bar per value of `by` (mean over its runs, std as error bar)."""
    import math

    groups = _groups(runs, by)
    for m in metrics:
        check_key(runs, m, "metric")
    plt, fig, axes = _figure(len(metrics))
    labels = [fmt(v) for v in groups]
    for ax, metric in zip(axes, metrics):
        means, stds = [], []
        for members in groups.values():
            vals = [float(r.get(metric)) for r in members if isinstance(r.get(metric), (int, float))]
            mean = sum(vals) / len(vals) if vals else math.nan
            means.append(mean)
            stds.append(math.sqrt(sum((v - mean) ** 2 for v in vals) / len(vals)) if vals else 0.0)
        ax.bar(labels, means, yerr=stds, capsize=3, color="tab:blue", alpha=0.8)
        ax.set_xlabel(by)
        ax.set_title(metric)
        ax.grid(axis="y", alpha=0.3)
    return _save(plt, fig, out)


# A panel per rate flattened into run.json after training (samp.eval.metrics.METRICS): success, reach, collision.
RATES = metric_keys(flat=True, rate=True)


def plot_run_summary(run: Run, out: Path) -> Path:
    """One policy run on one page: its train and val losses per step (metrics.csv) and, when it was
    evaluated, success, reach and collision rate per planner and split (eval/metrics.json)."""
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
    axes[0].legend(fontsize=8)
    splits = [s for s in ("train", "heldout") if any(s in m for _, m in planners)]
    for ax, rate in zip(axes[1:], RATES):
        for i, (name, metrics) in enumerate(planners):
            xs = [j + (i - (len(planners) - 1) / 2) * 0.25 for j in range(len(splits))]
            ax.bar(xs, [100 * (metrics.get(s, {}).get(rate) or 0.0) for s in splits], width=0.25, label=name)
        ax.set_xticks(range(len(splits)), [f"{s} scenes" for s in splits])
        ax.set(title=rate.replace("_", " ") + " [%]", ylim=(0, 119))
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=7, ncol=len(planners), loc="upper center")
    fig.suptitle(f"{run.get('experiment')}  {run.path.name}", fontsize=9)
    return _save(plt, fig, out)


def _save(plt, fig, out: Path) -> Path:
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.tight_layout()
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out
