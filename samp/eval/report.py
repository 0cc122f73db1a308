"""Evaluate one planner under the evaluation protocol and write its report: the step shared by
`python -m samp.eval` (a planner loaded from a run folder, or a built-in one) and the evaluation after
training (`samp.train.after_fit`, the model just trained, in memory).

The protocol (docs/design.md section 4, "protocol 2"): problems come in *sections*, each reported on its own —
"val" and "train" are the stored evaluation problems of a dataset's validation and training scenes (new
problems, never trained on), "test" those of its test scenes, "benchmark" the standing benchmark of
unseen scenes, and a section per further benchmark named (`benchmark=[unseen,hard]`: "hard", the problems
of `bench_hard`, every one drawn to need a detour). Beside the planner, the expert (its stored solutions and
planning times) and the straight joint-space line run on the same problems, always. A section's problems
whose straight line collides form its hard subset (`<section>_hard`; not for a benchmark drawn all hard);
each benchmark is also reported per scene generator (`benchmark_<generator>`, `hard_<generator>`). Every
rate carries its Wilson 95 % interval (`samp.eval.metrics`).

Into `out`: metrics.json ({"protocol": 2, "groups": {group: source and size}, "metrics" / "expert" /
"straight": {group: metrics}, ...}), metrics.md (the table), problems.jsonl (one record per problem and
planner, with its group) and, if `record`, recording.rrd (and reconstruction.rrd with reconstructed grids).
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, replace
from datetime import datetime, timezone
from pathlib import Path

from samp.cli import paste
from samp.console import plural

__all__ = ["CONSOLE_COLUMNS", "CONSOLE_WIDTH", "PROTOCOL", "Section", "benchmark_refs", "console_table", "dataset_sections",
           "evaluate_sections", "flat_report", "grid_source", "protocol_sections"]

PROTOCOL = 2  # metrics.json without a "protocol" key: version 1 (training demonstrations as problems)
PROGRESS_S = 10.0  # seconds between progress lines of an evaluation when stderr is not a terminal
HARD = "_hard"  # group suffix: the problems whose straight joint-space line collides


@dataclass
class Section:
    """Problems reported together. `grids`: where a policy's anchor grids come from; `source`: what the
    problems are, for the report; `reconstruction`: the `ReconstructedGrids` behind `grids`, if any."""

    name: str
    problems: list
    grids: object
    source: str
    reconstruction: object = None
    benchmark: str | None = None  # a benchmark's section: its dataset's `name@id` (metrics.json's "benchmarks")
    all_hard: bool = False  # every problem was drawn to need a detour: no hard subset of its own


def grid_source(cfg, ds, robot):
    """(grid source, its ReconstructedGrids or None): the dataset's exact grids, or grids reconstructed
    from simulated depth cameras (`grid_source=reconstructed`); collisions are checked exactly either way."""
    from samp.eval.problems import dataset_grids

    exact = dataset_grids(ds)
    if cfg.grid_source == "exact":
        return exact, None
    from samp.perception.source import ReconstructedGrids
    from samp.robot import load_robot
    from samp.robot.precision import exact_robot

    robot = robot or load_robot(ds.manifest["robot"]["name"])
    source = ReconstructedGrids(cfg.camera, exact_robot(robot), exact=exact, unknown=cfg.unknown)
    return source, source


def dataset_sections(ds, splits: list[str], count: int | None, seed: int, cfg, robot, name: str | None = None):
    """One `Section` per split of `ds` ("train" | "val" | "test"), from its stored evaluation problems;
    `name` renames a single section: a benchmark's, whose `ds` is the benchmark's dataset."""
    from samp.eval.benchmark import detour_only
    from samp.eval.problems import problems_from_dataset

    sections = []
    benchmark = f"{ds.name}@{ds.id}" if name else None
    all_hard = benchmark is not None and detour_only(ds)
    for split in splits:
        label = name or split
        problems = [replace(p, split=label) for p in problems_from_dataset(ds, split, count, seed, all_hard)]
        if not problems:
            raise ValueError(f"dataset {ds.name}@{ds.id} has no evaluation problems in its {split} scenes; pick other "
                             "splits (splits=[train,val]) or a dataset with such scenes")
        grids, reconstruction = grid_source(cfg, ds, robot)
        scenes = len({p.scene_index for p in problems})
        drawn = " drawn to need a detour (their straight line blocked)" if all_hard else ""
        source = f"{ds.name}@{ds.id}: {len(problems)} stored evaluation problems{drawn} in {scenes} {split} scene(s)"
        sections.append(Section(label, problems, grids, source, reconstruction, benchmark, all_hard))
    return sections


def protocol_sections(cfg, ds, benches, robot, trained=None):
    """The sections `cfg` asks for: the dataset's splits, then each benchmark (`samp.eval.benchmark.Benchmark`s,
    `open_benchmarks`); test and benchmark sections are checked against the scenes of `trained` (the dataset
    a run trained on)."""
    from samp.eval.benchmark import check_unseen, trained_scene_hashes

    sections = dataset_sections(ds, cfg.splits, cfg.problems, cfg.seed, cfg, robot) if ds is not None else []
    for b in benches:
        sections += dataset_sections(b.dataset, ["test"], cfg.benchmark_problems, cfg.seed, cfg, robot, name=b.section)
    if trained is not None:
        check_unseen(sections, trained_scene_hashes(trained), f"{trained.name}@{trained.id}")
    return sections


def _hard(straight_records: list[dict]) -> list[bool]:
    """Per problem: whether the straight joint-space line from start to goal collides."""
    return [bool(r["collision"]) for r in straight_records]


def _group_rows(section: Section, hard: list[bool]) -> dict[str, list[int]]:
    """Group name -> row indices into the section: the section, its hard subset (unless the section was drawn
    all hard) and, for a benchmark, each scene generator."""
    rows = {section.name: list(range(len(section.problems)))}
    if not section.all_hard:
        rows[section.name + HARD] = [i for i, h in enumerate(hard) if h]
    if section.benchmark is not None:
        for i, p in enumerate(section.problems):
            rows.setdefault(f"{section.name}_{_kind(p.scene)}", []).append(i)
    return rows


def _kind(scene) -> str:
    """The kind of scene a benchmark's rows are grouped by: its generator, "file" for a scene read from a
    file (samp.scene.files), else "unknown"."""
    meta = scene.meta or {}
    return meta.get("generator") or ("file" if meta.get("file") else "unknown")


def _subset(group: str, section: str) -> str:
    """What a subset group of `section` holds, for the report: 'benchmark_hard' -> 'the problems whose straight
    ...', 'benchmark_shelf' -> 'the problems in shelf scenes'."""
    if group == section + HARD:
        return "the problems whose straight joint-space line collides"
    return f"the problems in {group.removeprefix(section + '_')} scenes"


def _source_line(group: str, entry: dict) -> str:
    """A group's line in metrics.md: a section's source in full; a subset names its section instead."""
    section = entry.get("section", group)
    return f"- {group}: " + (entry["source"] if section == group else f"{_subset(group, section)} of `{section}`")


def _evaluate_section(planner, section: Section, cfg, expert) -> dict:
    """{planner name: evaluate result} for the planner, the expert (unless it is the planner) and the
    straight line, on one section."""
    from samp.eval.harness import evaluate
    from samp.eval.loading import load_planner

    rollout = cfg.rollout()
    start = time.perf_counter()
    print(f"{section.name}: {plural(len(section.problems), 'problem')}", flush=True)

    def timed(name: str, who, grids) -> None:
        t0 = time.perf_counter()
        results[name] = evaluate(who, section.problems, rollout, grids=grids, progress_s=PROGRESS_S)
        print(f"  {section.name}: {name} {time.perf_counter() - t0:.1f} s (rollouts and checks)", flush=True)

    results: dict = {}
    timed(planner.name, planner, section.grids)
    if cfg.compare_expert and planner.name != "expert":
        timed("expert", expert, None)
    if planner.name != "straight":  # always the floor (and it defines the hard subset)
        straight = load_planner("straight", robot=planner.robot if hasattr(planner, "robot") else None,
                                max_step=cfg.straight_max_step, n_e=cfg.n_e)
        timed("straight", straight, section.grids)
    print(f"{section.name}: {time.perf_counter() - start:.1f} s", flush=True)
    return results


def evaluate_sections(planner, sections: list[Section], cfg, out: Path, *, run_path: Path | None = None,
                      dataset: str | None = None, provenance=None) -> dict:
    """Evaluate `planner` (and the expert and the straight line) on every section, write the files into
    `out` (which must exist) and return the report (the content of metrics.json). `provenance`: a
    `samp.eval.binding.Provenance` (a run's checkpoint evaluated from its folder): its record goes into
    metrics.json and what it qualifies (another dataset, an unverified checkpoint) under the report's title.
    The report names each benchmark section's dataset (`benchmarks`: {section: `name@id`}) and the
    headline's alone as `benchmark`, from the sections."""
    from samp.eval.benchmark import HEADLINE
    from samp.eval.loading import load_planner
    from samp.eval.metrics import summarize

    benchmarks = {s.name: s.benchmark for s in sections if s.benchmark}
    if not sections:
        raise ValueError("nothing to evaluate: no sections (give splits=[train,val] and/or benchmark=NAME)")
    expert = load_planner("expert")
    groups, blocks, records, problems, results_all = {}, {}, [], [], []
    print(f"evaluating {planner.name}: " + ", ".join(plural(len(s.problems), f"{s.name} problem") for s in sections),
          flush=True)
    for section in sections:
        results = _evaluate_section(planner, section, cfg, expert)
        straight = results.get("straight") or results[planner.name]
        grouped = _group_rows(section, _hard(straight["records"]))
        for group, rows in grouped.items():
            subset = "" if group == section.name else _subset(group, section.name)
            groups[group] = {"source": section.source + (f"; {subset}" if subset else ""), "problems": len(rows),
                             "section": section.name}
            for name, result in results.items():
                m = summarize([result["records"][i] for i in rows], cfg.rollout())
                if group != section.name and "throughput" in m:  # batches mix the subsets: only the section's holds
                    m["throughput"] = None
                blocks.setdefault(name, {})[group] = m
        member: dict[int, list[str]] = {}
        for group, rows in grouped.items():
            for i in rows:
                member.setdefault(i, []).append(group)
        for name, result in results.items():  # "groups": every group a problem counts in, for intervals over runs
            records += [{**r, "group": section.name, "groups": member.get(i, [section.name])}
                        for i, r in enumerate(result["records"])]
        problems += section.problems
        results_all.append(results)
        if section.reconstruction is not None:
            print("  " + section.reconstruction.summary())
    report = {"protocol": PROTOCOL, "planner": planner.name, "run": str(run_path) if run_path else None,
              "dataset": dataset, "benchmark": benchmarks.get(HEADLINE), "benchmarks": benchmarks,
              "groups": groups, "metrics": blocks[planner.name],
              **{other: blocks.get(other) if planner.name != other else None for other in ("expert", "straight")}}
    if provenance is not None:
        report.update(provenance.record())
    heading = provenance.heading() if provenance is not None else ""
    return _write(out, cfg, report, planner, problems, records, results_all, sections, heading)


def benchmark_refs(report: dict) -> dict[str, str]:
    """{section: `name@id`} of the benchmarks a report (metrics.json) was evaluated on; one written before
    several benchmarks names its one as `benchmark`."""
    return report.get("benchmarks") or ({"benchmark": report["benchmark"]} if report.get("benchmark") else {})


def flat_report(report: dict, name: str) -> dict[str, float]:
    """The report's metrics as run.json and the trackers keep them: `eval/<planner>/<group>/<key>` for the
    metrics the registry flattens into run.json, each rate with its interval (`<rate>_ci_low`, `<rate>_ci_high`);
    `name` stands for the report's own planner."""
    from samp.eval.metrics import flat_metrics, metric_keys
    from samp.names import EVAL_PREFIX

    rates = set(metric_keys(rate=True))
    keys = [k for key in flat_metrics() for k in ([key, f"{key}_ci_low", f"{key}_ci_high"] if key in rates else [key])]
    return {f"{EVAL_PREFIX}{planner}/{group}/{key}": float(m[key])
            for planner, block in ((name, "metrics"), ("expert", "expert"), ("straight", "straight"))
            for group, m in (report.get(block) or {}).items() for key in keys if m.get(key) is not None}


def _merged(results_all: list[dict], name: str) -> dict | None:
    """One planner's results over every section, as one `evaluate` result (for the recording)."""
    parts = [r[name] for r in results_all if name in r]
    return {"planner": name, "records": [rec for p in parts for rec in p["records"]],
            "metrics": {k: v for p in parts for k, v in p["metrics"].items()}} if parts else None


# The printed table: these columns of metrics.md's (name of the metric, its header), to fit a terminal of
# CONSOLE_WIDTH columns; metrics.md keeps every column, the intervals and every tolerance.
CONSOLE_COLUMNS = (("success_rate", "success %"), ("collision_rate", "collision %"), ("reach_rate", "reach %"),
                   ("solution_time_b1", "time B=1 [s]"))
CONSOLE_WIDTH = 100


def console_table(rows: list[tuple[str, str, dict]], cfg, full: Path) -> str:
    """(planner, group, metrics) rows as the compact table printed after an evaluation: planner, group,
    problems, success, collision and reach rates (percent, at the stopping tolerance) and the solution
    time one problem at a time (mean ± std), aligned, then a note naming `full` (metrics.md), which holds
    the whole table. `cfg`: the `RolloutConfig` (its stopping tolerance is named)."""
    import textwrap

    from samp.eval.metrics import metric

    columns = [(metric(name), title) for name, title in CONSOLE_COLUMNS]
    header = ["planner", "group", "problems", *(title for _, title in columns)]
    body = [[planner, group, str(m.get("problems", 0)),
             *(c.column.cell([m.get(k) for k in c.keys()[:2 if c.stats == "mean_std" else 1]]) for c, _ in columns)]
            for planner, group, m in rows]
    widths = [max(len(r[i]) for r in [header, *body]) for i in range(len(header))]

    def line(cells: list[str]) -> str:  # numbers right-aligned, names left
        return "| " + " | ".join(c.ljust(w) if i < 2 else c.rjust(w) for i, (c, w) in enumerate(zip(cells, widths))) + " |"

    lines = [line(header), "|" + "|".join("-" * (w + 2) for w in widths) + "|", *(line(r) for r in body)]
    note = (f"Rates in percent, reached within {100 * cfg.position_tolerance:g} cm (success: reached with no "
            "violation); time: seconds per problem solved alone, mean ± std. The full table (95 % intervals, every "
            f"tolerance, path length, self-collision, joint limits, step time, throughput) is in {full}")
    return "\n".join(lines) + "\n\n" + textwrap.fill(note, CONSOLE_WIDTH, break_long_words=False, break_on_hyphens=False) + "\n"


def _write(out: Path, cfg, report: dict, planner, problems: list, records: list[dict], results_all: list[dict],
           sections: list[Section], heading: str = "") -> dict:
    """metrics.json, metrics.md, problems.jsonl and (if `record`) recording.rrd into `out`; `heading`: lines
    under metrics.md's title (and above the printed table)."""
    from dataclasses import asdict

    from samp.eval.metrics import markdown_table
    from samp.names import METRICS_JSON, METRICS_MD, PROBLEMS_JSONL, RECONSTRUCTION_RRD, RECORDING_RRD
    from samp.provenance import code_version

    rows = [(name, group, report[block][group]) for group in report["groups"]
            for name, block in ((report["planner"], "metrics"), ("expert", "expert"), ("straight", "straight"))
            if report.get(block) and group in report[block] and (block == "metrics" or name != report["planner"])]
    table = markdown_table(rows, cfg.rollout())
    sources = "\n".join(_source_line(g, v) for g, v in report["groups"].items() if not g.endswith(HARD))
    report.update(config=asdict(cfg), created=datetime.now(timezone.utc).isoformat(timespec="seconds"),
                  code_version=code_version())
    reconstructions = [s.reconstruction for s in sections if s.reconstruction is not None]
    if reconstructions:
        report["reconstruction"] = reconstructions[0].report()
    (out / METRICS_JSON).write_text(json.dumps(report, indent=2))
    title = f"# {report['planner']} (evaluation protocol {PROTOCOL})" + (f"\n\n{heading}" if heading else "")
    (out / METRICS_MD).write_text(f"{title}\n\n{sources}\n\n{table}")
    with open(out / PROBLEMS_JSONL, "w") as f:
        for rec in records:
            f.write(json.dumps(rec) + "\n")
    print("\n" + (heading + "\n\n" if heading else "") + sources + "\n\n" + console_table(rows, cfg.rollout(), out / METRICS_MD))
    written = [METRICS_JSON, METRICS_MD, PROBLEMS_JSONL]
    if cfg.record:
        from samp.eval.recording import write_recording

        path = write_recording(out / RECORDING_RRD, problems, _merged(results_all, planner.name),
                               _merged(results_all, "expert"), robot=getattr(planner, "robot", None),
                               record_rollouts=cfg.record_rollouts, record_points=cfg.record_points, metrics_md=table)
        written.append(f"{RECORDING_RRD} ({path.stat().st_size / 1e6:.1f} MB; open with `{paste('rerun', path)}`)")
        if reconstructions and reconstructions[0].scenes:
            from samp.perception.viz import write_reconstruction_recording

            path = write_reconstruction_recording(out / RECONSTRUCTION_RRD, reconstructions[0].scenes,
                                                  reconstructions[0].cameras)
            written.append(f"{RECONSTRUCTION_RRD} ({path.stat().st_size / 1e6:.1f} MB)")
    print(f"wrote {out}: " + ", ".join(written))
    return report
