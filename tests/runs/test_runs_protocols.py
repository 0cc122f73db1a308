"""`python -m samp.runs` over run folders evaluated under protocol 2 (groups val / train / benchmark, every
rate with its Wilson 95 % interval) and protocol 1 (train / held-out scenes), written here by hand: the
protocol in `ls` and `show`, rates as "rate [low, high]" in `compare` and `table`, the paper's tables from
the benchmark with a protocol-1 row marked, and the plots' error bars. Expected intervals are the roots of
the Wilson quadratic, computed here apart from `samp.eval.metrics.wilson_interval`."""

from __future__ import annotations

import json
import math
from statistics import NormalDist

import pytest

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

Z = NormalDist().inv_cdf(0.975)
DATASET, BENCH = "quickstart@a1b2c3d4e5f6", "bench_unseen@0f1e2d3c4b5a"
RATES = ("success_rate", "reach_rate", "collision_rate")
FLAT = (*(k for r in RATES for k in (r, f"{r}_ci_low", f"{r}_ci_high")), "path_length_mean", "solution_time_b1_mean",
        "step_time_b1_mean", "throughput")


def wilson(k: int, n: int) -> tuple[float, float]:
    """The roots p of (k/n - p)^2 = z^2 p (1 - p) / n, i.e. of (1 + z^2/n) p^2 - (2k/n + z^2/n) p + (k/n)^2."""
    a, b, c = 1 + Z * Z / n, -(2 * k / n + Z * Z / n), (k / n) ** 2
    root = math.sqrt(b * b - 4 * a * c)
    return (-b - root) / (2 * a), (-b + root) / (2 * a)


def pct(k: int, n: int) -> str:
    """"93.3 [84.1, 97.4]": k of n in percent with its interval, one decimal."""
    low, high = wilson(k, n)
    return f"{100 * k / n:.1f} [{100 * low:.1f}, {100 * high:.1f}]"


def summary(n: int, success: int, reach: int, collision: int, time_b1=0.0123, step_b1=0.0008, length=0.84) -> dict:
    """A protocol-2 summary of n problems, the rates as counts."""
    out = {"problems": n}
    for name, k in zip(RATES, (success, reach, collision)):
        low, high = wilson(k, n)
        out.update({name: k / n, f"{name}_ci_low": low, f"{name}_ci_high": high})
    return {**out, "path_length_mean": length, "path_length_std": 0.1, "solution_time_b1_mean": time_b1,
            "solution_time_b1_std": 0.002, "step_time_b1_mean": step_b1, "step_time_b1_std": 1e-4,
            "throughput": 850.0, "batch_size": 64, "timed_problems": 20}


def policy_groups(bench=(56, 57, 1), hard=(16, 17, 1)) -> dict:
    return {"val": summary(30, 27, 28, 1), "train": summary(30, 29, 29, 0), "benchmark": summary(60, *bench),
            "benchmark_hard": summary(20, *hard), "benchmark_tabletop": summary(15, 15, 15, 0),
            "hard": summary(40, 30, 35, 3)}


EXPERT = {"benchmark": summary(60, 60, 60, 0, time_b1=0.79, length=0.7), "benchmark_hard": summary(20, 20, 20, 0),
          "hard": summary(40, 40, 40, 0)}
STRAIGHT = {"benchmark": summary(60, 40, 60, 20, time_b1=0.002, length=0.9), "benchmark_hard": summary(20, 0, 20, 20),
            "hard": summary(40, 6, 40, 34)}


def protocol_2_run(root, experiment: str, start: str, policy: dict | None = None, **record):
    """A completed run evaluated under protocol 2: eval/metrics.json and run.json's flat metrics."""
    policy = policy or policy_groups()
    folder = root / experiment / start.replace(":", "-")
    (folder / "eval").mkdir(parents=True)
    blocks = {"samp": policy, "expert": EXPERT, "straight": STRAIGHT}
    flat = {f"eval/{planner}/{group}/{key}": m[key] for planner, groups in blocks.items()
            for group, m in groups.items() for key in FLAT}
    (folder / "run.json").write_text(json.dumps({"status": "completed", "experiment": experiment, "start": start,
                                                 "dataset_id": DATASET, "metrics": flat, **record}))
    groups = {g: {"source": f"{g} problems", "problems": m["problems"]} for g, m in policy.items()}
    (folder / "eval" / "metrics.json").write_text(json.dumps({
        "protocol": 2, "planner": "samp", "dataset": DATASET, "benchmark": BENCH, "groups": groups, "metrics": policy,
        "expert": EXPERT, "straight": STRAIGHT, "config": {}, "created": start, "code_version": {}}))
    return folder


def legacy(success, reach, collision, time_s, length, infer=None, n=100) -> dict:
    return {"problems": n, "success_rate": success, "reach_rate": reach, "collision_rate": collision,
            "solution_time_mean": time_s, "path_length_mean": length, "inference_time_mean": infer}


def protocol_1_run(root, experiment: str, start: str, **record):
    """A completed run evaluated under protocol 1 (no "protocol" key; train / held-out scenes)."""
    folder = root / experiment / start.replace(":", "-")
    (folder / "eval").mkdir(parents=True)
    metrics = {"train": legacy(0.82, 0.88, 0.10, 0.073, 0.8), "heldout": legacy(0.75, 0.83, 0.13, 0.074, 1.0),
               "all": legacy(0.785, 0.855, 0.115, 0.0735, 0.9, infer=1.5e-3, n=200)}
    flat = {f"eval/samp/{s}/{k}": m[k] for s, m in metrics.items() for k in ("success_rate", "reach_rate")}
    (folder / "run.json").write_text(json.dumps({"status": "completed", "experiment": experiment, "start": start,
                                                 "dataset_id": "paper@abc", "metrics": flat, **record}))
    (folder / "eval" / "metrics.json").write_text(json.dumps({
        "planner": "samp", "dataset": "paper@abc", "problems": {"train": 100, "heldout": 100}, "metrics": metrics,
        "expert": {"train": legacy(1.0, 1.0, 0.0, 0.79, 0.7), "heldout": legacy(1.0, 1.0, 0.0, 0.81, 0.8)}}))
    return folder


def _row(text: str, first: str) -> list[str]:
    """The cells of the markdown row whose first cell is `first`."""
    for line in text.splitlines():
        cells = [c.strip() for c in line.strip().strip("|").split("|")]
        if line.startswith("| ") and cells[0] == first:
            return cells
    raise AssertionError(f"no row {first!r} in:\n{text}")


@pytest.fixture
def runs(tmp_path):
    """(root, protocol-2 run, protocol-1 run, a run without evaluation)."""
    new = protocol_2_run(tmp_path, "samp_n100", "2026-03-01T00:00:00", seed=0)
    old = protocol_1_run(tmp_path, "samp_n40", "2026-01-01T00:00:00", seed=0)
    bare = tmp_path / "robot_sdf_panda" / "2026-02-01T00-00-00"
    bare.mkdir(parents=True)
    (bare / "run.json").write_text(json.dumps({"status": "completed", "experiment": "robot_sdf_panda",
                                               "start": "2026-02-01T00:00:00", "metrics": {"val/loss": 0.5}}))
    return tmp_path, new, old, bare


def test_protocol_of_each_run(runs):
    from samp.runs.registry import find_runs

    root, new, old, bare = runs
    got = {r.path: r.protocol for r in find_runs(root)}
    assert got == {new: 2, old: 1, bare: None}, f"expected protocols 2, 1, None, got {got}"


def test_ls_has_a_protocol_column_and_filters_by_it(runs, capsys):
    from samp.runs.__main__ import main

    root, new, old, bare = runs
    main(["ls", f"root={root}"])
    out = capsys.readouterr().out
    header = _row(out, "run")
    column = header.index("protocol")
    assert header[column - 1] == "dataset_id", header
    for folder, want in ((new, "2"), (old, "1 (legacy)"), (bare, "-")):
        cells = _row(out, f"{folder.parent.name}/{folder.name}")
        assert cells[column] == want, f"{folder.name}: expected protocol cell {want!r}, got {cells[column]!r}"
    assert "protocol 1 (legacy): problems from the demonstration trajectories" in out
    main(["ls", f"root={root}", "protocol=1"])
    out = capsys.readouterr().out
    assert old.name in out and new.name not in out and "1 run(s)" in out


def test_show_names_the_protocol_and_folds_intervals(runs, capsys):
    from samp.runs.__main__ import main

    _, new, old, bare = runs
    main(["show", str(new)])
    out = capsys.readouterr().out
    assert "protocol   2: new problems in the dataset's validation" in out and f"benchmark {BENCH}" in out, out
    assert f"| eval/samp/benchmark/success_rate [%] | {pct(56, 60)} |" in out
    assert f"| eval/straight/benchmark_hard/collision_rate [%] | {pct(20, 20)} |" in out
    assert "success_rate_ci_low" not in out, "the interval keys are shown with their rate, not as rows"
    assert "| eval/samp/benchmark/throughput | 850 |" in out
    main(["show", str(old)])
    out = capsys.readouterr().out
    assert "protocol   1 (legacy): problems from the demonstration trajectories" in out
    assert "| eval/samp/heldout/success_rate | 0.75 |" in out, "a protocol-1 run's metrics show as before"
    main(["show", str(bare)])
    assert "protocol   not evaluated" in capsys.readouterr().out


def test_compare_shows_rates_with_their_intervals(tmp_path, capsys):
    from samp.runs.__main__ import main

    a = protocol_2_run(tmp_path, "samp_n100", "2026-03-01T00:00:00", seed=0)
    b = protocol_2_run(tmp_path, "samp_n100", "2026-03-02T00:00:00", policy_groups(bench=(52, 55, 3)), seed=1)
    main(["compare", str(a), str(b)])
    out = capsys.readouterr().out
    for key, (ka, kb), n in (("eval/samp/benchmark/success_rate", (56, 52), 60),
                             ("eval/samp/benchmark/collision_rate", (1, 3), 60),
                             ("eval/samp/val/reach_rate", (28, 28), 30)):
        want = f"| {key} [%] | {pct(ka, n)} | {pct(kb, n)} |"
        assert want in out, f"expected {want!r} in:\n{out}"
    assert "_ci_high" not in out and "| eval/samp/benchmark/step_time_b1_mean | 0.0008 | 0.0008 |" in out
    assert "| protocol | 2 | 2 |" in out


def test_compare_across_protocols_warns(runs, capsys):
    from samp.runs.__main__ import main

    _, new, old, _ = runs
    main(["compare", str(old), str(new)])
    got = capsys.readouterr()
    assert "warning: these runs were evaluated under different protocols (1, 2)" in got.err, got.err
    assert "| protocol | 1 (legacy) | 2 |" in got.out
    assert "| eval/samp/heldout/success_rate | 0.75 | - |" in got.out


def problem_records(folder, outcomes: list[bool], planner="samp", group="benchmark") -> None:
    """eval/problems.jsonl for `folder`: one record per problem of `group`, its success as given."""
    with open(folder / "eval" / "problems.jsonl", "w") as f:
        for i, ok in enumerate(outcomes):
            f.write(json.dumps({"planner": planner, "problem": f"bench/scene0/problem{i}", "group": group,
                                "groups": [group], "success": {"2cm": ok}, "reached": {"2cm": True},
                                "collision": not ok, "self_collision": False,
                                "joint_limit_violation": False}) + "\n")


def test_table_interval_over_seeds_resamples_problems(tmp_path, capsys):
    """Two seeds on the same 60 problems: the interval is over problems, not over the 120 rollouts pooled, and
    runs without per-problem records show their mean and spread alone."""
    from samp.runs.__main__ import main

    a = protocol_2_run(tmp_path, "samp_n100", "2026-03-01T00:00:00", seed=0)
    b = protocol_2_run(tmp_path, "samp_n100", "2026-03-02T00:00:00", policy_groups(bench=(50, 55, 3)), seed=1)
    protocol_2_run(tmp_path, "samp_n40", "2026-03-03T00:00:00", policy_groups(bench=(45, 50, 6)), seed=0)
    protocol_2_run(tmp_path, "samp_n64", "2026-03-04T00:00:00", seed=0)
    protocol_2_run(tmp_path, "samp_n64", "2026-03-05T00:00:00", seed=1)
    first = [True] * 56 + [False] * 4
    second = [True] * 50 + [False] * 10  # fails the first one's four and six more
    problem_records(a, first)
    problem_records(b, second)
    key = "eval/samp/benchmark/success_rate"
    main(["table", str(tmp_path), "by=experiment", f"metrics={key}"])
    out = capsys.readouterr().out
    assert _row(out, "experiment")[3] == f"{key} [%]"
    rates = (56 / 60, 50 / 60)
    mean, std = sum(rates) / 2, abs(rates[0] - rates[1]) / 2  # the population std of two values
    cell = _row(out, "samp_n100")[3]
    head, _, bracket = cell.partition(" [")
    assert head == f"{100 * mean:.1f} ± {100 * std:.1f}", cell
    low, high = (float(x) / 100 for x in bracket.rstrip("]").split(", "))
    # oracle: the normal approximation of the mean over problems of the seeds' mean outcome
    per_problem = [(x + y) / 2 for x, y in zip(first, second)]
    m = sum(per_problem) / 60
    se = math.sqrt(sum((v - m) ** 2 for v in per_problem) / 59 / 60)
    assert abs(low - (m - Z * se)) < 0.02 and abs(high - (m + Z * se)) < 0.02, (cell, m - Z * se, m + Z * se)
    pooled_low, pooled_high = wilson(56 + 50, 120)
    assert high - low > pooled_high - pooled_low, "the seeds share their problems: wider than 120 pooled trials"
    assert _row(out, "samp_n40")[3] == pct(45, 60)  # one run: its own Wilson interval
    assert _row(out, "samp_n64")[3] == f"{100 * 56 / 60:.1f} ± 0.0", "no records: mean and spread, no interval"


def test_default_metrics_prefer_the_benchmark(tmp_path):
    from samp.runs.registry import find_runs
    from samp.runs.tables import default_metrics

    protocol_2_run(tmp_path, "samp_n100", "2026-03-01T00:00:00")
    got = default_metrics(find_runs(tmp_path))
    # what a policy is judged by first: success and collision, on the benchmark, its hard subset, the hard benchmark
    assert got[:6] == [f"eval/samp/{g}/{r}" for g in ("benchmark", "benchmark_hard", "hard")
                       for r in ("success_rate", "collision_rate")], got
    assert all("/benchmark/" in m for m in got[6:]), got
    assert all("_ci_" not in m for m in got), got


def test_paper_tables_come_from_the_benchmark(runs, capsys):
    from samp.runs.__main__ import main

    root, new, old, _ = runs
    protocol_1_run(root, "mpinet", "2026-01-05T00:00:00")
    main(["paper-tables", f"root={root}", f"out={root / 'tables'}"])
    one = (root / "tables" / "table_1.md").read_text()
    assert one.startswith(f"# Table I: motion planning, on the standing benchmark of unseen scenes (benchmark {BENCH}; "
                          f"datasets paper@abc, {DATASET})"), one.splitlines()[0]
    header = _row(one, "method")
    assert header[1:8] == ["soln. time, B = 1 [s]", "path length [m]", "success [%]", "collision [%]",
                           "hard subset success [%]", "hard benchmark success [%]", "hard benchmark collision [%]"], header
    source = f"samp_n100/{new.name} ({DATASET})"
    assert _row(one, "SAMP (100 anchors)") == ["SAMP (100 anchors)", "0.0123", "0.84", pct(56, 60), pct(1, 60),
                                               pct(16, 20), pct(30, 40), pct(3, 40), source]
    assert _row(one, "Expert (OMPL)") == ["Expert (OMPL)", "0.79", "0.7", pct(60, 60), pct(0, 60), pct(20, 20),
                                          pct(40, 40), pct(0, 40), source]
    assert _row(one, "Straight line (joint space)") == ["Straight line (joint space)", "0.002", "0.9", pct(40, 60),
                                                        pct(20, 60), pct(0, 20), pct(6, 40), pct(34, 40), source]
    assert _row(one, "MPiNet (protocol 1: train / held-out)")[1:8] == ["0.073 / 0.074", "0.8 / 1", "82 / 75",
                                                                       "10 / 13", "-", "-", "-"]
    assert _row(one, "MPNet") == ["MPNet", *["-"] * 8]
    assert "Rows marked (protocol 1)" in one and "[Wilson 95 % interval]" in one
    two = (root / "tables" / "table_2.md").read_text()
    assert _row(two, "anchors n_e")[2:6] == ["step time, B = 1 [s]", "success [%]", "reach [%]", "collision [%]"]
    assert _row(two, "100")[2:6] == ["0.0008", pct(56, 60), pct(57, 60), pct(1, 60)]
    assert _row(two, "40 (protocol 1: train / held-out)")[2:6] == ["0.0015", "82 / 75", "88 / 83", "10 / 13"]
    assert f"benchmark {BENCH}" in two.splitlines()[0] and "Table II" in capsys.readouterr().out


def test_a_protocol_2_run_fills_a_row_before_a_newer_protocol_1_run(tmp_path):
    from samp.runs.paper import paper_tables
    from samp.runs.registry import find_runs

    new = protocol_2_run(tmp_path, "samp_n100", "2026-01-01T00:00:00")
    protocol_1_run(tmp_path, "samp_n100", "2026-06-01T00:00:00")
    table = paper_tables(find_runs(tmp_path), tmp_path)["table_1"]
    assert _row("\n".join("| " + " | ".join(r) + " |" for r in table.rows), "SAMP (100 anchors)")[-1].startswith(
        f"samp_n100/{new.name}")


def _captured(monkeypatch) -> list:
    """The figures `samp.runs.plots` saves, as (path, [(y label, error bar segments) per axes])."""
    import samp.runs.plots as plots

    saved, save = [], plots.save_figure

    def spy(plt, fig, out, dpi=120):
        panels = []
        for ax in fig.axes:
            segments = [seg for container in ax.containers if getattr(container, "errorbar", None)
                        for seg in container.errorbar.lines[2][0].get_segments()]
            panels.append((ax.get_ylabel(), segments))
        saved.append((out, panels))
        return save(plt, fig, out, dpi)

    monkeypatch.setattr(plots, "save_figure", spy)
    return saved


def _png(path):
    from matplotlib.image import imread

    image = imread(path)
    assert image.shape[0] > 200 and image.shape[1] > 400 and image.std() > 0.01, f"{path}: {image.shape}"


def test_run_summary_plots_rates_with_wilson_error_bars(runs, monkeypatch):
    from samp.runs.plots import plot_run_summary
    from samp.runs.registry import load_run

    root, new, old, _ = runs
    saved = _captured(monkeypatch)
    for folder in (new, old):
        _png(plot_run_summary(load_run(folder), root / f"{folder.parent.name}.png"))
    (_, new_panels), (_, old_panels) = saved
    ylabel, segments = new_panels[1]  # success rate: policy, expert, straight over val, train, benchmark,
    assert ylabel == "error bars: Wilson 95 %" and len(segments) == 3 * 5, (ylabel, len(segments))  # its hard subset, hard
    low, high = wilson(30, 40)
    (_, got_low), (_, got_high) = segments[4]  # the policy's bar on the hard benchmark, last
    assert (got_low, got_high) == pytest.approx((100 * low, 100 * high)), (got_low, got_high)
    low, high = wilson(56, 60)
    (_, got_low), (_, got_high) = segments[2]  # the policy's bar on the benchmark
    assert (got_low, got_high) == pytest.approx((100 * low, 100 * high)), (got_low, got_high)
    _, segments = old_panels[1]  # protocol 1: policy and expert over train and held-out scenes, from the counts
    low, high = wilson(75, 100)
    assert len(segments) == 2 * 2 and [y for _, y in segments[1]] == pytest.approx([100 * low, 100 * high])


def test_bar_plots_show_intervals_over_problems_or_the_range(tmp_path, monkeypatch):
    from samp.runs.intervals import problem_bootstrap
    from samp.runs.plots import plot_bars
    from samp.runs.registry import find_runs

    new, old = tmp_path / "new", tmp_path / "old"
    first, second = [True] * 56 + [False] * 4, [True] * 50 + [False] * 10
    problem_records(protocol_2_run(new, "samp_n100", "2026-03-01T00:00:00", seed=0), first)
    problem_records(protocol_2_run(new, "samp_n100", "2026-03-02T00:00:00", policy_groups(bench=(50, 55, 3)), seed=1),
                    second)
    protocol_1_run(old, "samp_n40", "2026-01-01T00:00:00", seed=0)
    protocol_1_run(old, "samp_n40", "2026-01-02T00:00:00", seed=1)
    saved = _captured(monkeypatch)
    _png(plot_bars(find_runs(new), "experiment", ["eval/samp/benchmark/success_rate", "eval/samp/benchmark/throughput"],
                   tmp_path / "new.png"))
    _png(plot_bars(find_runs(old), "experiment", ["eval/samp/heldout/success_rate"], tmp_path / "old.png"))
    (_, (rate, throughput)), (_, (legacy_rate,)) = saved
    low, high = problem_bootstrap([{str(i): float(v) for i, v in enumerate(o)} for o in (first, second)])
    assert rate[0] == "mean of runs [%]; bars: 95 % over problems"
    assert [y for _, y in rate[1][0]] == pytest.approx([100 * low, 100 * high])
    assert throughput[0] == "mean of runs; bars: min to max", throughput[0]
    # protocol 1 kept no per-problem records: the range over the runs (both 75 %)
    assert legacy_rate[0] == "mean of runs [%]; bars: min to max", legacy_rate[0]
    assert [y for _, y in legacy_rate[1][0]] == pytest.approx([75.0, 75.0])
