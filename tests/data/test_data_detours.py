"""Problems that need a detour (`detour_share`): the recorded flags against an independent re-check of the
stored problems' straight lines in a fresh World built from the stored scene, the share the spec asks for,
the manifest's counts, the expert's own choice of the straight motion, and what `inspect` prints."""

from __future__ import annotations

import numpy as np
import pytest

from samp.data import generate, open_dataset, read_manifest
from samp.data.__main__ import main as data_main

SPEC = {"name": "detours", "robot": "panda", "seed": 3, "train_scenes": 1, "val_scenes": 1, "test_scenes": 0,
        "trajectories_per_scene": 6, "eval_problems_per_scene": 4, "detour_share": 0.5,
        "generators": ["tabletop", "shelf"], "resolutions": [8]}


@pytest.fixture(scope="module")
def detours(tmp_path_factory):
    root = tmp_path_factory.mktemp("datasets")
    return generate(SPEC, root=root, progress=False), root


def _blocked(world, start, goal, resolution: float, clearance: float) -> bool:
    """The straight joint-space line, sampled at `resolution` radians (both ends), has a state closer than
    `clearance` to an obstacle or in self-collision (written out here, not the sampler's helper)."""
    start, goal = np.asarray(start), np.asarray(goal)
    steps = max(1, int(np.ceil(np.linalg.norm(goal - start) / resolution)))
    states = start + np.linspace(0.0, 1.0, steps + 1)[:, None] * (goal - start)
    return bool(world.in_collision(states, margin=clearance).any())


def test_detour_flags_match_a_fresh_check_and_reach_the_share(detours, robots):
    from samp.sim import World

    folder, _ = detours
    ds, manifest = open_dataset(folder), read_manifest(folder)
    expert = manifest["config"]["expert_config"]
    assert manifest["config"]["detour_share"] == 0.5
    problems = [("demo", e) for e in ds.episodes] + [("eval", p) for p in ds.eval_problems]
    recount = {"demo": 0, "eval": 0}
    for i, scene in enumerate(ds.scenes):
        with World(robots["panda"], scene) as world:
            for what, e in problems:
                if e["scene"] != i:
                    continue
                if e["goal"] is None:
                    assert e["detour"] is None
                    continue
                blocked = _blocked(world, e["start"], e["goal"], expert["resolution"], expert["clearance"])
                assert e["detour"] is blocked, f"scene {i} {what} problem: recorded {e['detour']}, re-checked {blocked}"
                recount[what] += blocked
                if what == "demo" and e["success"]:  # the expert takes the straight motion exactly when it is free
                    assert e["stats"]["direct"] is (not blocked)
    # round(0.5 * 6) = 3 demonstrations and round(0.5 * 4) = 2 evaluation problems per scene are drawn blocked
    assert recount["demo"] >= 3 * len(ds.scenes) and recount["eval"] >= 2 * len(ds.scenes)
    assert manifest["counts"]["detours"] == recount["demo"]
    assert manifest["counts"]["eval_detours"] == recount["eval"]


def test_detour_share_zero_keeps_the_other_draws(detours, tmp_path, robots):
    """The detour choices come from a stream of their own: without them the starts and goal kinds of the
    problems that were not forced are drawn the same, and the first problem's start is the same."""
    from samp.expert.problems import sample_problems
    from samp.scene.registry import scene_from_config

    from samp.data.spec import load_spec

    spec = load_spec(SPEC)
    job = spec.scene_jobs()[0]
    scene = scene_from_config(spec.generator_config(job.generator), job.seed)
    cfg = spec.expert_config()
    plain = sample_problems(robots["panda"], scene, 6, 11, cfg)
    forced = sample_problems(robots["panda"], scene, 6, 11, cfg, detour_share=1.0)
    np.testing.assert_array_equal(plain[0].q_start, forced[0].q_start)
    assert [p.kind for p in plain] == [p.kind for p in forced]
    assert all(p.detour for p in forced if p.q_goal is not None)
    with pytest.raises(ValueError, match=r"detour_share must be in \[0, 1\]"):
        sample_problems(robots["panda"], scene, 1, 0, cfg, detour_share=-0.1)


def test_inspect_reports_the_detour_share(detours, capsys):
    folder, root = detours
    assert data_main(["inspect", f"dataset={folder.parent.name}@{folder.name}", f"root={root}"]) in (0, None)
    out = capsys.readouterr().out
    counts = read_manifest(folder)["counts"]
    demos = sum(e["goal"] is not None for e in open_dataset(folder).episodes)
    assert f"({counts['detours']}/{demos} with a goal)" in out
    assert "the spec asks for at least 50%" in out


def test_a_spec_without_detours_keeps_its_config_hash():
    """detour_share 0 (the default) is left out of the resolved spec, so a spec from before the key keeps its
    hash and its datasets (the standing benchmark's among them) are found instead of generated again."""
    from samp.data.spec import load_spec

    plain = {k: v for k, v in SPEC.items() if k != "detour_share"}
    assert "detour_share" not in load_spec(plain).resolved()
    assert load_spec(plain).config_hash() == load_spec({**plain, "detour_share": 0.0}).config_hash()
    assert load_spec(plain).config_hash() != load_spec(SPEC).config_hash()


def test_the_confirmation_benchmark_is_bench_unseens_recipe_on_other_scenes():
    """`benchmark=confirm` differs from the standing benchmark only where it must (its name, seed and scene
    namespace), so what it confirms is the same kind of measurement on scenes no one chose anything on."""
    from samp.data.spec import load_spec
    from samp.eval.benchmark import benchmark_spec

    unseen, confirm = (load_spec(benchmark_spec(name)).resolved() for name in ("unseen", "confirm"))
    assert {k for k in {*unseen, *confirm} if unseen.get(k) != confirm.get(k)} == {"name", "seed", "scene_namespace"}


def test_the_held_out_benchmark_is_bench_unseens_recipe_on_a_seed_and_namespace_of_its_own():
    """`benchmark=final` measures what bench_unseen does (more scenes of the same generators) on a seed and a
    scene namespace that no other spec uses, so none of its scenes or problems was ever read by a choice."""
    from samp.data import available_specs
    from samp.data.spec import load_spec
    from samp.eval.benchmark import benchmark_spec

    unseen, final = (load_spec(benchmark_spec(name)).resolved() for name in ("unseen", "final"))
    assert {k for k in {*unseen, *final} if unseen.get(k) != final.get(k)} == {
        "name", "seed", "scene_namespace", "test_scenes"}
    others = [load_spec(s).resolved() for s in available_specs() if s != "bench_final"]
    assert final["seed"] not in {o.get("seed") for o in others}
    assert final["scene_namespace"] not in {o.get("scene_namespace") for o in others}


def test_the_hard_benchmark_draws_every_problem_to_need_a_detour_on_scenes_of_its_own():
    """`benchmark=hard` is bench_unseen's kind of measurement on problems that need a detour: unseen scenes of
    every generator in a namespace no other spec uses, every problem drawn with its straight line blocked, and
    enough problems that at least 400 remain after the ~10 % without an IK goal."""
    from samp.data import available_specs
    from samp.data.spec import load_spec
    from samp.eval.benchmark import benchmark_spec

    hard = load_spec(benchmark_spec("hard"))
    unseen = load_spec(benchmark_spec("unseen"))
    assert hard.detour_share == 1.0 and hard.train_scenes == hard.val_scenes == hard.trajectories_per_scene == 0
    assert set(hard.generators) == set(unseen.generators) == {"tabletop", "shelf", "cabinet", "blocks"}
    assert hard.test_scenes * hard.eval_problems_per_scene * 0.85 >= 400
    namespaces = [load_spec(name).resolved().get("scene_namespace") or name for name in available_specs()]
    assert namespaces.count(hard.scene_namespace) == 1, "no other spec may draw the hard benchmark's scenes"
