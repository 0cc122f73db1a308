"""The pictures of one run, from its folder alone (metrics.csv, eval/metrics.json, eval/problems.jsonl and
the datasets the evaluation names), written into `<run>/plots/` after training and by
`python -m samp.runs plot RUN kind=run`:

- `learning.png`: every loss term logged (train per step, val per epoch), one panel each, and the learning
  rate (LearningRateMonitor) against the step;
- `outcomes.png`: success and collision rate per planner and group of problems with their Wilson 95 %
  intervals, the cumulative distribution of the final goal position error, and success on easy against
  hard problems (hard: the straight joint-space line from start to goal collides) with Wilson intervals;
- `sdf_slice.png`: a horizontal slice of one evaluated scene's anchor grid (the exact SDF stored in its
  dataset) at the height of the goal, with the policy's and the expert's end-effector paths on it.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from samp.console import plural
from samp.eval.metrics import wilson_interval
from samp.eval.report import benchmark_refs
from samp.names import EVAL_DIR, PLOTS_DIR, PROBLEMS_JSONL, TRAIN_PREFIX, VAL_PREFIX
from samp.runs.plots import save_figure
from samp.runs.registry import Run

__all__ = ["LEARNING_PNG", "OUTCOMES_PNG", "SDF_SLICE_PNG", "plot_learning", "plot_outcomes", "plot_run",
           "plot_sdf_slice"]

LEARNING_PNG, OUTCOMES_PNG, SDF_SLICE_PNG = "learning.png", "outcomes.png", "sdf_slice.png"
PLANNER_COLORS = {"expert": "tab:blue", "straight": "tab:gray"}  # the policy: tab:green


def _plt():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_learning(run: Run, out: Path) -> Path:
    """One panel per loss term (train/<term> per logged step, val/<term> per epoch) and the learning rate;
    ValueError when metrics.csv has no loss."""
    rows = run.curves()
    terms = sorted({k[len(TRAIN_PREFIX):] for r in rows for k in r if k.startswith(TRAIN_PREFIX)} |
                   {k[len(VAL_PREFIX):] for r in rows for k in r if k.startswith(VAL_PREFIX)})
    rates = sorted({k for r in rows for k in r if k.startswith("lr-")})
    if not terms:
        raise ValueError(f"{run.path} has no train/ or val/ losses in its metrics.csv")
    plt = _plt()
    n = len(terms) + bool(rates)
    cols = min(n, 3)
    fig, axes = plt.subplots(math.ceil(n / cols), cols, figsize=(4.6 * cols, 3.4 * math.ceil(n / cols)), squeeze=False)
    axes = axes.ravel()
    for ax, term in zip(axes, terms):
        for prefix, style in ((TRAIN_PREFIX, "-"), (VAL_PREFIX, "o-")):
            pts = [(r["step"], r[prefix + term]) for r in rows if prefix + term in r and "step" in r]
            if pts:
                ax.plot(*zip(*pts), style, ms=3, lw=1, label=prefix.rstrip("/"))
        if all(v > 0 for line in ax.get_lines() for v in line.get_ydata()):
            ax.set_yscale("log")
        ax.set(title="loss" if term == "loss" else f"loss term: {term}", xlabel="step")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    if rates:
        ax = axes[len(terms)]
        for key in rates:
            pts = [(r["step"], r[key]) for r in rows if key in r and "step" in r]
            ax.plot(*zip(*pts), lw=1, label=key[3:])
        ax.set(title="learning rate", xlabel="step")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    for ax in axes[n:]:
        ax.axis("off")
    fig.suptitle(f"{run.get('experiment')}  {run.path.name}: learning curves", fontsize=9)
    return save_figure(plt, fig, out, dpi=110)


def _records(run: Run) -> list[dict]:
    path = run.path / EVAL_DIR / PROBLEMS_JSONL
    if not path.is_file():
        raise ValueError(f"{run.path} has no {EVAL_DIR}/{PROBLEMS_JSONL}: it was not evaluated")
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]


def _rate(flags: list[bool]) -> tuple[float, float, float]:
    """(rate, error below, error above) in percent, the errors from the Wilson 95 % interval."""
    if not flags:
        return math.nan, math.nan, math.nan
    k, n = sum(flags), len(flags)
    low, high = wilson_interval(k, n)
    return 100 * k / n, 100 * (k / n - low), 100 * (high - k / n)


def _primary(record: dict) -> bool:
    return bool(record["success"][next(iter(record["success"]))])  # the stopping tolerance comes first


def plot_outcomes(run: Run, out: Path) -> Path:
    """Success and collision per planner and section, the goal-error CDF, success against difficulty."""
    records = _records(run)
    planners = list(dict.fromkeys(r["planner"] for r in records))
    sections = list(dict.fromkeys(r["group"] for r in records))
    hard = {(r["group"], r["problem"]): bool(r["collision"]) for r in records if r["planner"] == "straight"}
    plt = _plt()
    fig, axes = plt.subplots(1, 4, figsize=(19, 3.9))
    width = 0.8 / max(1, len(planners))
    for ax, (title, flag) in zip(axes[:2], (("success", _primary), ("collision", lambda r: bool(r["collision"])))):
        for i, name in enumerate(planners):
            bars = [_rate([flag(r) for r in records if r["planner"] == name and r["group"] == s]) for s in sections]
            xs = np.arange(len(sections)) + (i - (len(planners) - 1) / 2) * width
            ax.bar(xs, [b[0] for b in bars], width, yerr=[[b[1] for b in bars], [b[2] for b in bars]], capsize=2,
                   label=name, color=PLANNER_COLORS.get(name, "tab:green"))
        ax.set_xticks(range(len(sections)), sections)
        ax.set(title=f"{title} rate [%] (Wilson 95 %)", ylim=(0, 115))
        ax.grid(axis="y", alpha=0.3)
        ax.legend(fontsize=7, ncol=len(planners), loc="upper center")
    ax = axes[2]
    for name in planners:
        errors = np.sort([r["position_error"] for r in records if r["planner"] == name and r["position_error"] is not None])
        if len(errors):  # errors below 0.1 mm are drawn at 0.1 mm (a log axis)
            errors = np.maximum(errors, 1e-4)
            ax.step(np.concatenate([[1e-4], errors]), np.linspace(0, 1, len(errors) + 1), where="post", label=name,
                    color=PLANNER_COLORS.get(name, "tab:green"))
    ax.axvline(0.02, color="k", ls=":", lw=1, label="2 cm")
    ax.set_xscale("log")
    ax.set(title="final goal position error (CDF, all sections)", xlabel="error [m] (0.1 mm and below at the left)",
           ylabel="fraction of problems", ylim=(0, 1.02))
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    ax = axes[3]
    for i, name in enumerate(planners):
        mine = [r for r in records if r["planner"] == name and (r["group"], r["problem"]) in hard]
        bars = [_rate([_primary(r) for r in mine if hard[(r["group"], r["problem"])] == h]) for h in (False, True)]
        xs = np.arange(2) + (i - (len(planners) - 1) / 2) * width
        ax.bar(xs, [b[0] for b in bars], width, yerr=[[b[1] for b in bars], [b[2] for b in bars]], capsize=2,
               label=name, color=PLANNER_COLORS.get(name, "tab:green"))
    counts = [sum(1 for v in hard.values() if v == h) for h in (False, True)]
    ax.set_xticks(range(2), [f"straight line clear\n({plural(counts[0], 'problem')})",
                             f"straight line collides\n({counts[1]})"])
    ax.set(title="success against difficulty [%] (Wilson 95 %)", ylim=(0, 115))
    ax.grid(axis="y", alpha=0.3)
    ax.legend(fontsize=7, ncol=len(planners), loc="upper center")
    fig.suptitle(f"{run.get('experiment')}  {run.path.name}: outcomes per problem", fontsize=9)
    return save_figure(plt, fig, out, dpi=110)


def _scene_of(run: Run, record: dict):
    """(scene, grid (n_e,)^3, n_e) of an evaluated problem, from the dataset its section came from."""
    from samp.data import open_dataset

    report = run.evaluation or {}
    ref = benchmark_refs(report).get(record["group"]) or report.get("dataset")
    if ref is None:
        raise ValueError(f"{run.path}'s evaluation names no dataset for its {record['group']!r} problems "
                         "(eval/metrics.json): there is no anchor grid to draw")
    root = (report.get("config") or {}).get("root")
    ds = open_dataset(ref, root=root) if root else open_dataset(ref)
    n_e = max(ds.resolutions)
    return ds.scenes[record["scene_index"]], ds.grid(record["scene_index"], n_e).numpy(), n_e


def plot_sdf_slice(run: Run, out: Path, problem: int = 0) -> Path:
    """The anchor grid of the scene of the policy's `problem`-th evaluated problem, sliced at the goal's
    height, with the policy's and the expert's end-effector paths drawn over it (x, y)."""
    import torch

    from samp.robot import load_robot
    from samp.scene import anchor_points

    records = _records(run)
    policy = [r for r in records if r["planner"] not in ("expert", "straight")] or records
    record = policy[min(problem, len(policy) - 1)]
    expert = next((r for r in records if r["planner"] == "expert" and r["problem"] == record["problem"]
                   and r["group"] == record["group"]), None)
    scene, grid, n_e = _scene_of(run, record)
    robot = load_robot(run.robot or "panda", dtype=torch.float64)

    def ee(traj) -> np.ndarray:
        with torch.no_grad():
            return robot.fk(torch.as_tensor(np.asarray(traj), dtype=torch.float64))[robot.ee_link][:, :3, 3].numpy()

    goal = ee([record["q_goal"]])[0]
    anchors = np.asarray(anchor_points(n_e, scene.bounds))  # (n_e, n_e, n_e, 3)
    k = int(np.argmin(np.abs(anchors[0, 0, :, 2] - goal[2])))
    (x0, y0, _), (x1, y1, _) = scene.bounds
    plt = _plt()
    fig, ax = plt.subplots(figsize=(6.4, 5.4))
    vmax = 0.3
    dx, dy = (x1 - x0) / (n_e - 1), (y1 - y0) / (n_e - 1)  # each pixel centred on its anchor
    image = ax.imshow(grid[:, :, k].T, origin="lower", extent=(x0 - dx / 2, x1 + dx / 2, y0 - dy / 2, y1 + dy / 2),
                      cmap="RdBu", vmin=-vmax, vmax=vmax)
    ax.contour(anchors[:, 0, k, 0], anchors[0, :, k, 1], grid[:, :, k].T, levels=[0.0], colors="k", linewidths=1)
    fig.colorbar(image, ax=ax, label="signed distance [m] (0: black line)")
    path = ee(record["trajectory"])
    ax.plot(path[:, 0], path[:, 1], color="tab:green" if _primary(record) else "tab:red", lw=2,
            label=f"{record['planner']} ({'success' if _primary(record) else 'failure'})")
    if expert is not None:
        e = ee(expert["trajectory"])
        ax.plot(e[:, 0], e[:, 1], color="tab:blue", lw=1.5, ls="--", label="expert")
    ax.plot(*path[0, :2], "o", color="0.3", label="start")
    ax.plot(*goal[:2], "*", color="gold", ms=14, mec="k", label="goal")
    ax.set(xlabel="x [m]", ylabel="y [m]", title=f"{record['problem']}\nanchor grid n_e={n_e}, slice z={anchors[0, 0, k, 2]:.3f} m "
           "(paths projected)")
    ax.title.set_fontsize(8)
    ax.legend(fontsize=7, loc="lower right")
    return save_figure(plt, fig, out, dpi=110)


def plot_run(run: Run, folder: Path | None = None) -> list[Path]:
    """Every picture the run's files allow, into `folder` (default `<run>/plots/`); the paths written."""
    folder = Path(folder) if folder else run.path / PLOTS_DIR
    written = []
    if any(k.startswith((TRAIN_PREFIX, VAL_PREFIX)) for r in run.curves() for k in r):
        written.append(plot_learning(run, folder / LEARNING_PNG))
    if (run.path / EVAL_DIR / PROBLEMS_JSONL).is_file():
        written.append(plot_outcomes(run, folder / OUTCOMES_PNG))
        if (run.evaluation or {}).get("dataset") or (run.evaluation or {}).get("benchmark"):
            written.append(plot_sdf_slice(run, folder / SDF_SLICE_PNG))
    return written
