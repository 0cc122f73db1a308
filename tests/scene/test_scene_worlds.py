"""cuRobo-style worlds and robometrics-style problem sets read as scenes (`samp.scene.worlds`, `.files`).

Oracles: the analytic distance to a box, a cylinder and a capsule (the distance to a segment minus the
radius) at points around them, the refusals naming file and entry, and problem-set references."""

from __future__ import annotations

import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

YAW = 0.4  # radians about z: the cuboid is turned, so the quaternion's order matters
QUAT_WXYZ = [float(np.cos(YAW / 2)), 0.0, 0.0, float(np.sin(YAW / 2))]


def write(path, data) -> str:
    path.write_text(json.dumps(data) if path.suffix == ".json" else _yaml(data))
    return str(path)


def _yaml(data) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False)


def box_distance(p, centre, R, half):
    """Exact signed distance to an oriented box: p (N, 3), R (3, 3) box -> base, half (3,) half extents."""
    q = np.abs((p - centre) @ R) - half
    return np.linalg.norm(np.maximum(q, 0), axis=1) + np.minimum(q.max(axis=1), 0)


def capsule_distance(p, a, b, r):
    """Signed distance to the capsule of radius r around the segment a-b."""
    t = np.clip((p - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
    return np.linalg.norm(p - (a + t[:, None] * (b - a)), axis=1) - r


@pytest.fixture
def points():
    return np.random.default_rng(0).uniform([-0.2, -0.6, -0.1], [1.0, 0.6, 1.0], size=(4000, 3))


def test_a_cuboid_is_the_box_it_describes(tmp_path, points):
    from samp.scene.files import load_scene_file

    ref = write(tmp_path / "w.yaml", {"cuboid": {"crate": {"dims": [0.3, 0.2, 0.1],
                                                           "pose": [0.5, 0.1, 0.3, *QUAT_WXYZ]}}})
    scene = load_scene_file(ref)
    (box,) = scene.obstacles
    assert box.kind == "box" and box.name == "crate" and scene.meta["source"] == "world"
    R = Rotation.from_euler("z", YAW).as_matrix()
    want = box_distance(points, np.array([0.5, 0.1, 0.3]), R, np.array([0.15, 0.1, 0.05]))
    got = np.asarray(scene.sdf(points), dtype=np.float64)
    np.testing.assert_allclose(got, want, atol=1e-5, err_msg="sdf of the read cuboid vs the analytic box distance")


def test_a_cylinder_is_centred_on_its_pose_along_its_z(tmp_path):
    from samp.scene.files import load_scene_file

    quarter_about_x = [float(np.cos(np.pi / 4)), float(np.sin(np.pi / 4)), 0.0, 0.0]  # local z -> base -y
    bar = {"radius": 0.05, "height": 0.6, "pose": [0.5, 0.0, 0.4, *quarter_about_x]}
    scene = load_scene_file(write(tmp_path / "w.json", {"cylinder": {"bar": bar}}))
    # The axis runs from y = -0.3 to 0.3 at x = 0.5, z = 0.4: beside it, 1 cm inside its end, beyond its end.
    p = np.array([[0.5, 0.0, 0.5], [0.5, 0.29, 0.4], [0.5, 0.4, 0.4], [0.6, -0.1, 0.4], [0.5, 0.0, 0.4]])
    np.testing.assert_allclose(np.asarray(scene.sdf(p), dtype=np.float64), [0.05, -0.01, 0.1, 0.05, -0.05], atol=1e-6)


def test_a_capsule_is_the_union_of_a_cylinder_and_two_spheres(tmp_path, points):
    from samp.scene.files import load_scene_file

    base, tip, r = np.array([0.0, -0.2, 0.1]), np.array([0.1, 0.25, 0.3]), 0.07
    ref = write(tmp_path / "w.yaml", {"capsule": {"rod": {"radius": r, "base": base.tolist(), "tip": tip.tolist(),
                                                          "pose": [0.5, 0.0, 0.2, *QUAT_WXYZ]}}})
    scene = load_scene_file(ref)
    assert sorted(o.kind for o in scene.obstacles) == ["cylinder", "sphere", "sphere"]
    R = Rotation.from_euler("z", YAW).as_matrix()
    a, b = R @ base + [0.5, 0.0, 0.2], R @ tip + [0.5, 0.0, 0.2]
    want = capsule_distance(points, a, b, r)
    got = np.asarray(scene.sdf(points), dtype=np.float64)
    # Outside, the union's distance is the capsule's exactly; inside, the union's is the deepest part's, which
    # for a capsule (whose every part holds the same ball around the segment's nearest point) is the same.
    np.testing.assert_allclose(got, want, atol=1e-5, err_msg="capsule union vs the analytic capsule distance")


def test_spheres_by_pose_or_position_and_style_keys_read_past(tmp_path):
    from samp.scene.files import load_scene_file

    scene = load_scene_file(write(tmp_path / "w.yaml", {
        "sphere": {"a": {"radius": 0.1, "position": [0.5, 0.0, 0.5], "color": [1, 0, 0, 1]},
                   "b": {"radius": 0.1, "pose": [0.5, 0.5, 0.5, 1, 0, 0, 0]}},
        "cuboid": {"a": {"dims": [0.1, 0.1, 0.1], "pose": [0, 0.5, 0.1, 1, 0, 0, 0]}}}))
    assert [o.name for o in scene.obstacles] == ["cuboid_a", "sphere_a", "b"]  # a name under two keys is qualified
    assert float(scene.sdf(np.array([[0.5, 0.0, 0.7]]))[0]) == pytest.approx(0.1, abs=1e-6)


def test_a_mesh_path_is_relative_to_the_world_file(tmp_path):
    import trimesh

    from samp.scene.files import load_scene_file

    trimesh.creation.box((0.2, 0.2, 0.2)).export(tmp_path / "crate.obj")
    scene = load_scene_file(write(tmp_path / "w.yaml", {"mesh": {"crate": {"file_path": "crate.obj", "scale": [2, 2, 2],
                                                                           "pose": [0.5, 0, 0.2, 1, 0, 0, 0]}}}))
    assert float(scene.sdf(np.array([[0.5, 0.0, 0.5]]))[0]) == pytest.approx(0.1, abs=1e-4)


POSE = [0, 0, 0, 1, 0, 0, 0]


@pytest.mark.parametrize("world, says", [
    ({"cuboid": {"crate": {"dims": [0.1, 0.1, 0.1], "pose": POSE, "mass": 2}}}, "cuboid 'crate': unknown keys ['mass']"),
    ({"cuboid": {"crate": {"dims": [0.1, 0.1, 0.1], "pose": [0, 0, 0, 0.9, 0, 0, 0]}}}, "cuboid 'crate': quaternion"),
    ({"cuboid": {"crate": {"dims": [0.1, float("nan"), 0.1], "pose": POSE}}}, "cuboid 'crate': dims must be finite"),
    ({"sphere": {"ball": {"radius": -0.1, "position": [0, 0, 0]}}}, "sphere 'ball': radius must be positive"),
    ({"cylinder": {"post": {"radius": 0.1, "pose": POSE}}}, "cylinder 'post': height is missing"),
    ({"cuboid": {"crate": {"dims": [0.1, 0.1, 0.1]}}}, "cuboid 'crate': `pose`"),
])
def test_refusals_name_the_file_and_the_entry(tmp_path, world, says):
    from samp.scene.files import load_scene_file

    path = tmp_path / "bad.json"  # JSON: YAML cannot write a NaN that every loader reads back
    path.write_text(json.dumps(world))
    with pytest.raises(ValueError) as err:
        load_scene_file(path)
    message = str(err.value)
    assert message.startswith(f"scene file {path}: ") and says in message and "\n" not in message, message


def test_a_quaternion_off_by_rounding_is_renormalised(tmp_path):
    from samp.scene.files import load_scene_file
    from samp.scene.worlds import QUATERNION_TOLERANCE

    off = [0.9763, 0, 0, -0.2164]  # norm 0.999995: four digits of a 25 degree turn
    scene = load_scene_file(write(tmp_path / "w.yaml", {"cuboid": {"c": {"dims": [0.1, 0.1, 0.1],
                                                                         "pose": [0.5, 0, 0.5, *off]}}}))
    assert abs(np.linalg.norm(scene.obstacles[0].pose.quaternion) - 1) < 1e-12
    assert QUATERNION_TOLERANCE < 0.01


PROBLEM = {"start": [0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785],
           "goal_ik": [[0.3, -0.5, 0.0, -2.0, 0.0, 1.6, 0.785], [0.4, -0.5, 0.0, -2.0, 0.0, 1.6, 0.785]],
           "goal_pose": {"frame": "panda_hand", "position_xyz": [0.5, 0.0, 0.4], "quaternion_wxyz": [0, 1, 0, 0]},
           "collision_buffer_ik": 0, "world_frame": "panda_link0",
           "obstacles": {"cuboid": {"wall": {"dims": [0.05, 0.6, 0.5], "pose": [0.7, 0, 0.25, 1, 0, 0, 0]}}}}


def test_a_problem_set_gives_one_scene_per_obstacle_set_with_its_problems(tmp_path):
    from samp.scene.files import file_problems, load_scene_file, resolve_scene_file, scene_refs

    post = {"radius": 0.05, "height": 0.8, "pose": [0.6, 0.3, 0.4, 1, 0, 0, 0]}
    other = {**PROBLEM, "obstacles": {"cylinder": {"post": post}}}
    ref = write(tmp_path / "set.yaml", {"walls": [PROBLEM, other, {**PROBLEM, "start": [0.1] * 7}]})
    refs = scene_refs(ref)
    assert refs == [f"{ref}#walls/0", f"{ref}#walls/1"]  # problems 0 and 2 share the wall
    problems = file_problems(resolve_scene_file(refs[0]))
    assert [p.where for p in problems] == ["walls/0", "walls/2"]
    np.testing.assert_array_equal(problems[0].goals, PROBLEM["goal_ik"])
    scene = load_scene_file(f"{ref}#walls/2")  # any problem names its group's scene
    assert scene.name == "set_walls_0" and [o.name for o in scene.obstacles] == ["wall"]
    with pytest.raises(ValueError, match="a problem set of 2 scenes; name one as FILE#TYPE/INDEX"):
        load_scene_file(ref)
    with pytest.raises(ValueError, match="no problem 'walls/7'"):
        load_scene_file(f"{ref}#walls/7")


def test_a_problem_with_an_unknown_key_is_refused_by_name(tmp_path):
    from samp.scene.files import scene_refs

    ref = write(tmp_path / "set.yaml", {"walls": [{**PROBLEM, "goal_joints": []}]})
    with pytest.raises(ValueError, match=r"set.yaml: problem walls/0: unknown keys \['goal_joints'\]"):
        scene_refs(ref)


def test_folders_and_globs_expand_sorted_and_relative(tmp_path, monkeypatch):
    from samp.scene.files import scene_refs

    for name in ("b", "a", "c"):
        ball = {"radius": 0.05, "position": [0.5, 0, 0.1 + ord(name) / 1000]}
        write(tmp_path / f"{name}.yaml", {"sphere": {"s": ball}})
    (tmp_path / "notes.txt").write_text("not a scene")
    assert scene_refs(str(tmp_path)) == [str(tmp_path / f"{n}.yaml") for n in "abc"]
    assert scene_refs(str(tmp_path / "[ab].yaml")) == [str(tmp_path / f"{n}.yaml") for n in "ab"]
    with pytest.raises(ValueError, match="matches no file"):
        scene_refs(str(tmp_path / "*.urdf"))


def test_show_reads_a_world_file(tmp_path, capsys):
    from samp.scene.__main__ import main

    crate = {"dims": [0.2, 0.2, 0.2], "pose": [0.5, 0, 0.1, 1, 0, 0, 0]}
    ref = write(tmp_path / "cell.yaml", {"cuboid": {"crate": crate}})
    assert main(["show", f"file={ref}", "n_e=8", f"out={tmp_path / 'cell.rrd'}"]) == 0
    out = capsys.readouterr().out
    assert "scene cell: from file cell.yaml (world)" in out and "obstacles     1: 1 box" in out, out
    assert (tmp_path / "cell.rrd").is_file()
