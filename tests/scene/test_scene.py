"""Scene model (round trip, hash, validation) and the generators (determinism, clear base, target)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from samp.scene import Box, Cylinder, MeshObstacle, Pose, Scene, Sphere, available_generators, generate_scene
from samp.scene.registry import BASE_CLEARANCE, REACH

GENERATORS = ["blocks", "cabinet", "shelf", "tabletop"]
BROAD = ["around", "clutter", "cubbies", "walls"]  # tests/scene/test_generators_broad.py


def test_all_generators_are_configured():
    assert available_generators() == sorted(GENERATORS + BROAD)


def _mixed_scene() -> Scene:
    return Scene("mixed", obstacles=(
        Box("b", (0.1, 0.2, 0.3), Pose((0.1, 0.2, 0.3), (0.0, 0.0, np.sin(0.35), np.cos(0.35)))),
        Cylinder("c", 0.05, 0.3, Pose((0.5, -0.2, 0.15))),
        Sphere("s", 0.1 / 3, Pose((1 / 3, 0.0, 0.5))),
        MeshObstacle("m", "pybullet_data://duck_vhacd.obj", 0.1, Pose((0.6, 0.3, 0.1)))),
        target=Box("target", (0.05, 0.05, 0.08), Pose((0.45, 0.0, 0.04))), meta={"note": "test"})


def test_to_dict_from_dict_is_exact():
    scene = _mixed_scene()
    d = scene.to_dict()
    assert Scene.from_dict(d) == scene
    assert Scene.from_dict(d).to_dict() == d
    through_json = Scene.from_dict(json.loads(json.dumps(d)))
    assert through_json == scene and through_json.content_hash() == scene.content_hash()
    for name in GENERATORS:
        s = generate_scene(name, seed=2)
        assert Scene.from_dict(json.loads(json.dumps(s.to_dict()))) == s


@pytest.mark.parametrize("name", GENERATORS)
def test_same_seed_same_hash_other_seed_other_hash(name):
    a, b, c = generate_scene(name, seed=11), generate_scene(name, seed=11), generate_scene(name, seed=12)
    assert a == b and a.content_hash() == b.content_hash()
    assert a.content_hash() != c.content_hash()


def test_hash_covers_geometry_and_mesh_files_not_names():
    scene = _mixed_scene()
    renamed = Scene.from_dict({**scene.to_dict(), "name": "other", "meta": {}})
    assert renamed.content_hash() == scene.content_hash()
    d = scene.to_dict()
    d["obstacles"][1]["radius"] += 1e-9
    assert Scene.from_dict(d).content_hash() != scene.content_hash()


@pytest.mark.parametrize("name", GENERATORS)
def test_generated_scenes_keep_base_clear_and_target_reachable(name):
    axis = np.stack([np.zeros(50), np.zeros(50), np.linspace(0.0, 0.6, 50)], axis=1)
    for seed in range(8):
        scene = generate_scene(name, seed=seed)
        others = Scene("o", obstacles=tuple(o for o in scene.all_obstacles if o.name != "table"))
        assert others.sdf(axis).min() >= BASE_CLEARANCE - 1e-9, f"{name} seed {seed}: obstacle near the base"
        x, y, z = scene.target.pose.position
        assert REACH[0] <= np.hypot(x, y) <= REACH[1]
        # The target stands on something: directly below its bottom face there is an obstacle.
        below = np.array([[x, y, z - scene.target.size[2] / 2 - 0.005]])
        assert Scene("o", obstacles=scene.obstacles).sdf(below)[0] < 0.006, f"{name} seed {seed}: target floats"
        assert scene.sdf(np.array([[x, y, z]]))[0] < 0, "the target is part of the scene's SDF"
        assert len(scene.obstacles) >= 2 and scene.obstacles[0].name == "table"


def test_generator_parameters_change_the_scene():
    few = generate_scene("tabletop", seed=0, num_obstacles=[2, 2])
    many = generate_scene("tabletop", seed=0, num_obstacles=[14, 14])
    assert len(few.obstacles) == 3 and len(many.obstacles) == 15  # + the table
    t = generate_scene("blocks", seed=0, mode="t")
    assert {o.name for o in t.obstacles} == {"table", "t_bar", "t_stem"}


def test_unknown_generator_lists_available():
    with pytest.raises(ValueError, match=r"unknown scene generator 'forest'; available: around, blocks, cabinet, clutter, "
                       r"cubbies, shelf, tabletop, walls"):
        generate_scene("forest")


def test_unknown_generator_parameter():
    with pytest.raises(ValueError, match=r"scene generator 'shelf' has no parameters \['colour'\]; valid: \["):
        generate_scene("shelf", colour="red")


@pytest.mark.parametrize("make, message", [
    (lambda: Box("b", (0.1, -0.2, 0.3)), r"box 'b': size must be positive"),
    (lambda: Cylinder("c", 0.1, 0.0), r"cylinder 'c': height must be positive"),
    (lambda: Sphere("s", -1.0), r"sphere 's': radius must be positive"),
    (lambda: MeshObstacle("m", "x.obj", scale=-2.0), r"mesh 'm': scale must be positive"),
    (lambda: Pose((0, 0, 0), (0, 0, 0, 2)), r"must be a unit quaternion"),
    (lambda: Scene("s", bounds=((0, 0, 1), (1, 1, 1))), r"bounds need min < max on every axis"),
    (lambda: Scene("s", obstacles=(Sphere("a", 1.0), Sphere("a", 2.0))), r"obstacle names must be unique"),
    (lambda: generate_scene("tabletop", box=[-0.1, 0.2]), r"box must be a range \[min, max\] with 0 <= min <= max"),
    (lambda: Scene.from_dict({"name": "s", "obstacles": [{"kind": "cone"}]}), r"unknown obstacle kind 'cone'"),
])
def test_bad_input_is_refused_with_a_message(make, message):
    with pytest.raises(ValueError, match=message):
        make()
