"""The generators of cells unlike the original four (around, clutter, walls, cubbies): determinism, a clear
base axis, a target within reach with a free approach, their parameter ranges, and one tiny dataset planned
by the expert in one of them; the dataset specs that mix them load and hash."""

from __future__ import annotations

import numpy as np
import pytest

from samp.scene import Box, Cylinder, Scene, Sphere, generate_scene
from samp.scene.registry import REACH, base_is_clear, target_is_approachable

BROAD = ["around", "clutter", "walls", "cubbies"]
SEEDS = range(12)


def lowest_point(o) -> float:
    """The lowest z of a primitive, from its pose: a box's corners, a cylinder's two rims, a sphere's centre."""
    T = o.pose.matrix()
    if isinstance(o, Sphere):
        return T[2, 3] - o.radius
    if isinstance(o, Box):
        corners = np.array(np.meshgrid(*[[-s / 2, s / 2] for s in o.size])).reshape(3, -1)  # (3, 8)
        return float((T[:3, :3] @ corners + T[:3, 3:])[2].min())
    if isinstance(o, Cylinder):
        # A rim's lowest point lies radius * |horizontal part of the axis| below its centre.
        axis = T[:3, 2]
        rims = T[2, 3] + np.array([-1, 1]) * axis[2] * o.height / 2
        return float(rims.min() - o.radius * np.hypot(axis[0], axis[1]))
    raise TypeError(f"no lowest point for {type(o).__name__}")


@pytest.mark.parametrize("name", BROAD)
def test_same_seed_same_scene_other_seed_other_scene(name):
    a, b, c = generate_scene(name, seed=5), generate_scene(name, seed=5), generate_scene(name, seed=6)
    assert a == b and a.content_hash() == b.content_hash(), f"{name}: seed 5 gave two scenes"
    assert a.content_hash() != c.content_hash(), f"{name}: seeds 5 and 6 gave the same scene"


@pytest.mark.parametrize("name", BROAD)
def test_base_clear_target_reachable_and_approachable(name):
    for seed in SEEDS:
        scene = generate_scene(name, seed=seed)
        assert base_is_clear(scene), f"{name} seed {seed}: an obstacle near the base axis"
        assert target_is_approachable(scene), f"{name} seed {seed}: no free pre-grasp point at the target"
        x, y, z = scene.target.pose.position
        assert REACH[0] <= np.hypot(x, y) <= REACH[1], f"{name} seed {seed}: target at {np.hypot(x, y):.3f} m"
        # The target stands on something: just below its bottom face there is an obstacle.
        below = np.array([[x, y, z - scene.target.size[2] / 2 - 0.005]])
        assert Scene("o", obstacles=scene.obstacles).sdf(below)[0] < 0.006, f"{name} seed {seed}: target floats"
        assert scene.obstacles[0].name == "table" and len(scene.obstacles) >= 2


@pytest.mark.parametrize("name", BROAD)
def test_obstacles_stay_inside_the_workspace_bounds(name):
    """The policy sees the scene through an anchor grid over the bounds: nothing but the table may leave them."""
    for seed in SEEDS:
        scene = generate_scene(name, seed=seed)
        lo, hi = np.asarray(scene.bounds)
        for o in scene.all_obstacles[1:]:
            x, y, z = o.pose.position
            assert lo[0] < x < hi[0] and lo[1] < y < hi[1] and z < hi[2], f"{name} seed {seed}: {o.name} at {x, y, z}"


def test_clutter_count_within_range_and_every_item_floats():
    counts = []
    for seed in SEEDS:
        scene = generate_scene("clutter", seed=seed, num_obstacles=[5, 40])
        items = scene.obstacles[1:]
        counts.append(len(items))
        assert 5 <= len(items) <= 40, f"seed {seed}: expected 5 to 40 items, got {len(items)}"
        low = min(lowest_point(o) for o in items)
        assert low > 0.0, f"seed {seed}: an item reaches down to z = {low:.4f} m, expected every item above the table"
    assert len(set(counts)) > 3, f"clutter counts should vary with the seed, got {counts}"
    exact = generate_scene("clutter", seed=0, num_obstacles=[12, 12], kinds=["sphere"])
    assert len(exact.obstacles) == 13 and {o.kind for o in exact.obstacles[1:]} == {"sphere"}


def test_around_puts_obstacles_behind_and_above_the_base():
    behind = above = 0
    for seed in range(20):
        scene = generate_scene("around", seed=seed)
        behind += any(o.pose.position[0] < 0 for o in scene.obstacles[1:])
        above += any(o.name == "overhead" for o in scene.obstacles)
        for o in scene.obstacles:
            if o.name == "overhead":
                assert 0.85 <= o.pose.position[2] <= 1.15, f"seed {seed}: overhead at {o.pose.position[2]:.3f} m"
    assert behind >= 15, f"expected obstacles behind the base (x < 0) in most of 20 seeds, got {behind}"
    assert 8 <= above <= 19, f"expected a plate or beam overhead in about 3 of 4 of 20 seeds, got {above}"
    none = generate_scene("around", seed=0, overhead_share=0.0, num_obstacles=[6, 6])
    assert len(none.obstacles) == 7 and all(o.name != "overhead" for o in none.obstacles)


def test_walls_and_cubbies_modes():
    for seed in range(6):
        window = {o.name for o in generate_scene("walls", seed=seed, mode="window").obstacles}
        assert {"wall_left", "wall_right", "stand"} <= window, f"seed {seed}: {sorted(window)}"
        corridor = {o.name for o in generate_scene("walls", seed=seed, mode="corridor").obstacles}
        assert corridor == {"table", "corridor_left", "corridor_right"}, f"seed {seed}: {sorted(corridor)}"
        grid = generate_scene("cubbies", seed=seed, mode="grid")
        assert all(o.name == "table" or o.name.startswith("cubby_") for o in grid.obstacles)
        cage = generate_scene("cubbies", seed=seed, mode="cage")
        assert all(o.name == "table" or o.name.startswith("cage_") for o in cage.obstacles)
        bars = [o for o in cage.obstacles if o.name.startswith("cage_front")]
        assert len(bars) >= 2 and all(0.01 <= o.size[0] <= 0.025 for o in bars), f"seed {seed}: front bars {bars}"
        plinth = next(o for o in cage.obstacles if o.name == "cage_plinth")
        assert 0.1 <= plinth.size[2] <= 0.2 and abs(cage.target.pose.position[2] - plinth.size[2] - 0.03) < 1e-9
    # An opening as wide as the cage allows (its width less 0.1 m) leaves no room to shift it sideways.
    tight = generate_scene("cubbies", seed=0, mode="cage", cage_width=[0.4, 0.4], opening=[0.5, 0.5])
    assert target_is_approachable(tight)
    narrow = generate_scene("walls", seed=0, mode="window", wall_width=[0.5, 0.5], window_width=[0.4, 0.4])
    assert base_is_clear(narrow) and target_is_approachable(narrow)
    with pytest.raises(ValueError, match="walls mode"):
        generate_scene("walls", seed=0, mode="maze")


@pytest.mark.parametrize("name", BROAD)
def test_a_hundred_seeds_each_give_a_scene(name):
    """Every draw of a range must be well formed: a seed of a dataset once hit an empty range by a rounding."""
    hashes = {generate_scene(name, seed=seed).content_hash() for seed in range(100)}
    assert len(hashes) == 100, f"{name}: expected 100 distinct scenes from 100 seeds, got {len(hashes)}"


@pytest.mark.parametrize("spec", ["cpu_broad", "bench_around", "bench_clutter", "bench_walls", "bench_cubbies"])
def test_broad_specs_load_and_hash(spec):
    from samp.data.spec import load_spec

    loaded = load_spec(spec)
    assert len(loaded.config_hash()) == 64
    assert set(loaded.generators) <= {"tabletop", "shelf", "cabinet", "blocks", *BROAD}


def test_family_benchmarks_hold_out_one_family_each_in_a_namespace_of_their_own():
    from samp.data.spec import available_specs, load_spec

    benches = {g: load_spec(f"bench_{g}") for g in BROAD}
    for family, spec in benches.items():
        assert spec.generators == [family] and spec.train_scenes == spec.val_scenes == 0 and spec.test_scenes > 0
    train_specs = [load_spec(s) for s in available_specs() if not s.startswith("bench_")]
    used = {(s.seed, s.namespace) for s in train_specs}
    for family, spec in benches.items():
        assert (spec.seed, spec.namespace) not in used, f"bench_{family} shares seed and namespace with a training spec"
    assert load_spec("cpu_broad").generators == ["tabletop", "shelf", "cabinet", "blocks", *BROAD]


def test_one_tiny_dataset_in_a_new_generator_is_planned_by_the_expert(tmp_path):
    from samp.data import generate, open_dataset

    spec = {"name": "tiny_clutter", "robot": "panda", "seed": 3, "train_scenes": 1, "val_scenes": 0,
            "trajectories_per_scene": 2, "eval_problems_per_scene": 2, "generators": ["clutter"],
            "resolutions": [12]}
    dataset = open_dataset(generate(spec, root=tmp_path, progress=False))
    assert [s.meta["generator"] for s in dataset.scenes] == ["clutter"]
    assert len(dataset) == 2, f"expected the expert to plan both demonstrations, got {len(dataset)}"
    info = dataset.manifest["scenes"][0]
    assert (info["eval_problems"], info["eval_solved"]) == (2, 2), f"expected 2 of 2 evaluation problems solved, got {info}"
