"""The evaluation protocol (samp.eval.report): sections with one job each, the hard subset from the
straight line, intervals and B = 1 times in metrics.json, the expert row from stored solutions, and the
refusal to report a scene the run trained on as unseen (by content hash)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from samp.data import generate, open_dataset

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

DATA = {"name": "proto_data", "robot": "panda", "seed": 5, "train_scenes": 1, "val_scenes": 1, "test_scenes": 0,
        "trajectories_per_scene": 2, "eval_problems_per_scene": 3, "generators": ["tabletop", "shelf"],
        "resolutions": [12]}
BENCH = {"name": "proto_bench", "robot": "panda", "seed": 5, "scene_namespace": "tests/proto_bench", "train_scenes": 0,
         "val_scenes": 0, "test_scenes": 2, "trajectories_per_scene": 0, "eval_problems_per_scene": 3,
         "generators": ["tabletop", "shelf"], "resolutions": [12]}


@pytest.fixture(scope="module")
def datasets(tmp_path_factory, _isolated_cache):
    root = tmp_path_factory.mktemp("protocol")
    return (open_dataset(generate(DATA, root=root, progress=False)),
            open_dataset(generate(BENCH, root=root, progress=False)))


def _config(**kw):
    from samp.eval.config import load_eval_config

    return load_eval_config({"problems": None, "record": False, "timed_problems": 2, "overwrite": True, **kw})


class Line:
    """The straight line under another name, as "the planner": its records must equal the straight row's."""

    def __init__(self, robot):
        from samp.eval.planners import StraightLinePolicy

        self._line = StraightLinePolicy(robot)
        self.robot, self.n_e, self.name = robot, None, "line"

    def step(self, q, q_goal, env):
        return self._line.step(q, q_goal, env)


@pytest.fixture(scope="module")
def evaluated(datasets, panda, tmp_path_factory):
    """The folder the evaluation of the line on the dataset's splits and the benchmark wrote."""
    from samp.eval.benchmark import Benchmark
    from samp.eval.report import evaluate_sections, protocol_sections

    ds, bench = datasets
    cfg = _config()
    sections = protocol_sections(cfg, ds, [Benchmark("benchmark", bench)], panda, trained=ds)
    out = tmp_path_factory.mktemp("out")
    evaluate_sections(Line(panda), sections, cfg, out, dataset=f"{ds.name}@{ds.id}")
    return out


@pytest.fixture(scope="module")
def report(evaluated):
    return (json.loads((evaluated / "metrics.json").read_text()),
            [json.loads(x) for x in open(evaluated / "problems.jsonl")])


@pytest.fixture(scope="module")
def metrics_md(evaluated):
    return (evaluated / "metrics.md").read_text()


def test_sections_hold_the_stored_evaluation_problems_of_their_scenes(datasets, report):
    ds, bench = datasets
    data, records = report
    assert data["protocol"] == 2 and data["benchmark"] == f"{bench.name}@{bench.id}"
    assert {g: v["problems"] for g, v in data["groups"].items() if not g.endswith("_hard")} == {
        "val": 3, "train": 3, "benchmark": 6, "benchmark_tabletop": 3, "benchmark_shelf": 3}
    # every problem is one of the datasets' stored evaluation problems, not a training demonstration
    stored = {tuple(np.round(p["start"], 9)) + tuple(np.round(p["goal"], 9)) for p in ds.eval_problems + bench.eval_problems}
    demos = {tuple(np.round(t[0].numpy(), 9)) + tuple(np.round(t[-1].numpy(), 9)) for t in ds.trajectories}
    keys = {tuple(np.round(r["q_start"], 9)) + tuple(np.round(r["q_goal"], 9)) for r in records}
    assert keys <= stored and not keys & demos
    assert {r["group"] for r in records} == {"val", "train", "benchmark"}
    assert {r["planner"] for r in records} == {"line", "expert", "straight"}, "the expert and the line are always rows"


def test_metrics_md_gives_each_source_once_and_names_the_section_of_a_subset(datasets, report, metrics_md):
    """metrics.md lists what each group is: a section with its dataset and problem count, a scene-generator
    subset as its generator and its section (not the section's whole source again)."""
    ds, bench = datasets
    data, _ = report
    lines = [line for line in metrics_md.splitlines() if line.startswith("- ")]
    assert lines == [f"- val: {data['groups']['val']['source']}", f"- train: {data['groups']['train']['source']}",
                     f"- benchmark: {data['groups']['benchmark']['source']}",
                     "- benchmark_tabletop: the problems in tabletop scenes of `benchmark`",
                     "- benchmark_shelf: the problems in shelf scenes of `benchmark`"]
    assert f"{bench.name}@{bench.id}" in lines[2] and f"{ds.name}@{ds.id}" in lines[0]
    assert data["groups"]["benchmark_shelf"]["section"] == "benchmark"


def test_the_hard_subset_is_where_the_straight_line_collides(report):
    data, records = report
    for section in ("val", "train", "benchmark"):
        straight = [r for r in records if r["planner"] == "straight" and r["group"] == section]
        hard = sum(r["collision"] for r in straight)
        assert data["groups"][f"{section}_hard"]["problems"] == hard
        if hard:  # the line, rolled out as "the planner", collides on exactly those problems
            assert data["metrics"][f"{section}_hard"]["collision_rate"] == 1.0
            assert data["straight"][f"{section}_hard"]["success_rate"] == 0.0
        # each record names the groups it counts in: the section, its hard subset where the line collides
        for planner in ("line", "expert", "straight"):
            mine = [r for r in records if r["planner"] == planner and r["group"] == section]
            assert [f"{section}_hard" in r["groups"] for r in mine] == [r["collision"] for r in straight]
            assert all(r["groups"][0] == section for r in mine)
    per_generator = [r for r in records if r["planner"] == "straight" and r["group"] == "benchmark"]
    for group, entry in data["groups"].items():  # the records' groups count what metrics.json says each holds
        if entry.get("section") == "benchmark":
            assert sum(group in r["groups"] for r in per_generator) == entry["problems"], group


def test_every_rate_has_its_interval_and_times_are_per_problem(report):
    from samp.eval.metrics import wilson_interval

    data, _ = report
    m = data["metrics"]["benchmark"]
    k = round(m["success_rate"] * m["problems"])
    assert (m["success_rate_ci_low"], m["success_rate_ci_high"]) == pytest.approx(wilson_interval(k, m["problems"]))
    for block in ("metrics", "expert", "straight"):
        for group, g in data[block].items():
            for rate in ("success_rate", "reach_rate", "collision_rate"):
                if g.get("problems"):
                    assert g[rate + "_ci_low"] <= g[rate] <= g[rate + "_ci_high"], (block, group, rate)
    assert m["timed_problems"] == 2 and m["solution_time_b1_mean"] > 0 and m["step_time_b1_mean"] > 0
    assert m["throughput"] > 0
    expert = data["expert"]["benchmark"]
    assert expert["timed_problems"] == 6, "the expert answers one problem at a time: its planning times"


def test_a_benchmark_scene_the_run_trained_on_is_refused(datasets, panda):
    """A dataset evaluated as its own 'benchmark': its scenes are the training ones, by content hash."""
    from samp.eval.benchmark import Benchmark
    from samp.eval.report import protocol_sections

    ds, bench = datasets
    with pytest.raises(ValueError, match="trained or validated on.*cannot be reported as unseen"):
        protocol_sections(_config(splits=[]), None, [Benchmark("benchmark", ds_as_test(ds))], panda, trained=ds)
    protocol_sections(_config(splits=[]), None, [Benchmark("benchmark", bench)], panda, trained=ds)  # unseen pass
    assert not set(bench.scene_hashes) & set(ds.scene_hashes)


def ds_as_test(ds):
    """The same dataset with every scene relabelled as a test scene (what a careless spec could produce)."""
    import copy

    clone = copy.copy(ds)
    clone.scene_split = ["test"] * len(ds.scene_split)
    clone.eval_problems = [{**p, "split": "test"} for p in ds.eval_problems]
    return clone


def _drawn_hard(ds):
    """The benchmark as if its spec drew every problem to need a detour (`detour_share: 1`), with the sampler's
    fallback on every third problem (an ordinary goal, `detour` false) so that there is something to leave out."""
    import copy

    clone = copy.copy(ds)
    clone.manifest = {**ds.manifest, "config": {**(ds.manifest.get("config") or {}), "detour_share": 1.0}}
    clone.eval_problems = [{**p, "detour": i % 3 != 0} for i, p in enumerate(ds.eval_problems)]
    return clone


def test_a_second_benchmark_drawn_all_hard_is_its_own_section(datasets, panda, tmp_path):
    """`benchmark=[unseen,hard]`: the second benchmark is the section "hard", holding exactly its stored problems
    drawn with a blocked straight line (an oracle read from the dataset itself), reported per generator and
    without a hard subset of its own; its scenes are checked as unseen like the first benchmark's. (That a
    spec with `detour_share: 1` draws blocked lines is tests/data/test_data_detours.py's.)"""
    from samp.eval.benchmark import Benchmark
    from samp.eval.report import evaluate_sections, protocol_sections

    ds, bench = datasets
    hard = _drawn_hard(bench)
    cfg = _config(splits=[])
    sections = protocol_sections(cfg, None, [Benchmark("benchmark", bench), Benchmark("hard", hard)], panda,
                                 trained=ds)
    assert [s.name for s in sections] == ["benchmark", "hard"]
    assert len(sections[0].problems) == len([p for p in bench.eval_problems if p["goal"] is not None])
    wanted = {(p["scene"], tuple(np.round(p["goal"], 9))) for p in hard.eval_problems
              if p.get("detour") is True and p["goal"] is not None}
    got = {(p.scene_index, tuple(np.round(p.q_goal, 9))) for p in sections[1].problems}
    assert got == wanted and len(got) < len(sections[0].problems)
    report = evaluate_sections(Line(panda), sections, cfg, tmp_path)
    groups = {g: v["problems"] for g, v in report["groups"].items()}
    assert groups["hard"] == len(wanted) and "hard_hard" not in groups and "benchmark_hard" in groups
    assert groups["hard_tabletop"] + groups["hard_shelf"] == len(wanted)
    assert report["benchmarks"] == {"benchmark": f"{bench.name}@{bench.id}", "hard": f"{hard.name}@{hard.id}"}
    assert report["benchmark"] == f"{bench.name}@{bench.id}"
    with pytest.raises(ValueError, match="cannot be reported as unseen"):
        protocol_sections(cfg, None, [Benchmark("benchmark", bench), Benchmark("hard", ds_as_test(ds))],
                          panda, trained=ds)


@pytest.mark.parametrize("value, names", [(None, []), ("unseen", ["unseen"]), (["unseen", "hard"], ["unseen", "hard"])])
def test_benchmark_takes_a_name_a_list_or_null(value, names):
    from samp.eval.benchmark import benchmark_names

    assert benchmark_names(_config(benchmark=value).benchmark) == names


@pytest.mark.parametrize("value", [["unseen", "unseen"], ["unseen", "val"], ["a/b"], [""]])
def test_a_bad_benchmark_list_is_refused(value):
    with pytest.raises(ValueError, match="benchmark must be"):
        _config(benchmark=value)


def test_benchmark_rows_are_grouped_by_generator_and_file_scenes_as_file(tmp_path):
    """A benchmark's per-kind rows: a generated scene by its generator, a scene read from a file as "file"
    (not "unknown"), through the scene files' own loader."""
    from samp.eval.report import _kind
    from samp.scene import generate_scene
    from samp.scene.files import load_scene_file

    world = tmp_path / "cell.yaml"
    world.write_text("cuboid:\n  crate:\n    dims: [0.2, 0.2, 0.2]\n    pose: [0.5, 0.0, 0.3, 1, 0, 0, 0]\n")
    assert _kind(generate_scene("shelf", seed=1)) == "shelf"
    assert _kind(load_scene_file(world)) == "file"
