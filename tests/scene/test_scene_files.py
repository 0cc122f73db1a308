"""Scenes from files: samp's scene JSON/YAML (meshes by relative path) and a cell URDF.

Oracles: the signed distance at points whose distance is known by construction (a point above a box,
inside a cylinder), the scene a generator writes read back unchanged, and the content hash of the same cell
copied to another folder."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

CELL_URDF = """<robot name="cell">
 <link name="world"/>
 <link name="bench"><collision><geometry><box size="0.4 0.6 0.1"/></geometry></collision></link>
 <link name="post"><collision><origin rpy="1.5707963 0 0"/><geometry><cylinder radius="0.05" length="0.6"/></geometry></collision></link>
 <link name="target"><collision><geometry><sphere radius="0.03"/></geometry></collision></link>
 <joint name="a" type="fixed"><parent link="world"/><child link="bench"/><origin xyz="0.6 0 0.05"/></joint>
 <joint name="b" type="fixed"><parent link="bench"/><child link="post"/><origin xyz="0 0 0.5"/></joint>
 <joint name="c" type="fixed"><parent link="world"/><child link="target"/><origin xyz="0.5 -0.3 0.3"/></joint>
</robot>"""


@pytest.fixture
def mesh_scene(tmp_path):
    import trimesh

    folder = tmp_path / "cell"
    folder.mkdir()
    trimesh.creation.box((0.2, 0.2, 0.2)).export(folder / "crate.obj")
    scene = {"obstacles": [{"kind": "box", "name": "table", "size": [1.0, 1.0, 0.04],
                            "pose": {"position": [0.5, 0.0, -0.02]}},
                           {"kind": "mesh", "name": "crate", "path": "crate.obj",
                            "pose": {"position": [0.5, 0.3, 0.1]}}],
             "target": {"kind": "box", "name": "target", "size": [0.04, 0.04, 0.08],
                        "pose": {"position": [0.5, -0.2, 0.04]}}}
    (folder / "cell.json").write_text(json.dumps(scene))
    return folder / "cell.json"


def test_scene_json_with_a_relative_mesh(mesh_scene, tmp_path):
    from samp.scene.files import load_scene_file

    scene = load_scene_file(mesh_scene)
    assert scene.name == "cell" and [o.name for o in scene.obstacles] == ["table", "crate"]
    d = float(scene.sdf(np.array([[0.5, 0.3, 0.3]]))[0])  # 0.1 m above the crate's top face
    assert d == pytest.approx(0.1, abs=1e-4)
    moved = tmp_path / "elsewhere"
    shutil.copytree(mesh_scene.parent, moved)
    assert load_scene_file(moved / "cell.json").content_hash() == scene.content_hash()
    (moved / "crate.obj").write_text((moved / "crate.obj").read_text().replace("0.1", "0.12", 1))
    assert load_scene_file(moved / "cell.json").content_hash() != scene.content_hash()


def test_a_generated_scene_reads_back_unchanged(tmp_path):
    from samp.scene import generate_scene
    from samp.scene.files import load_scene_file

    scene = generate_scene("shelf", seed=3)
    (tmp_path / "s.json").write_text(json.dumps(scene.to_dict()))
    back = load_scene_file(tmp_path / "s.json")
    assert back.content_hash() == scene.content_hash() and back.name == scene.name


def test_cell_urdf_poses_links_through_fixed_joints(tmp_path):
    from samp.scene.files import load_scene_file

    (tmp_path / "cell.urdf").write_text(CELL_URDF)
    scene = load_scene_file(tmp_path / "cell.urdf")
    assert [o.name for o in scene.obstacles] == ["bench", "post"] and scene.target.name == "target"
    post = scene.obstacles[1]
    assert np.allclose(post.pose.position, [0.6, 0.0, 0.55])
    # the post lies along y (rolled by 90 degrees): a point 0.25 m along y from its centre is inside it
    assert float(scene.sdf(np.array([[0.6, 0.25, 0.55]]))[0]) < 0
    assert float(scene.sdf(np.array([[0.6, 0.0, 0.7]]))[0]) == pytest.approx(0.1, abs=1e-4)
    assert float(scene.sdf(np.array([[0.5, -0.3, 0.4]]))[0]) == pytest.approx(0.07, abs=1e-4)


def test_bad_scene_files_are_refused_clearly(tmp_path):
    from samp.scene.files import load_scene_file

    (tmp_path / "moving.urdf").write_text(CELL_URDF.replace('name="a" type="fixed"', 'name="a" type="revolute"'))
    with pytest.raises(ValueError, match=r"moving.urdf: a cell URDF must have fixed joints only; \['a'\] move"):
        load_scene_file(tmp_path / "moving.urdf")
    (tmp_path / "typo.json").write_text(json.dumps({"obstacle": []}))
    with pytest.raises(ValueError, match=r"typo.json: unknown keys \['obstacle'\]"):
        load_scene_file(tmp_path / "typo.json")
    (tmp_path / "nan.json").write_text('{"obstacles": [{"kind": "sphere", "name": "s", "radius": NaN}]}')
    with pytest.raises(ValueError, match="nan.json: sphere 's': radius must be positive"):
        load_scene_file(tmp_path / "nan.json")
    with pytest.raises(ValueError, match="unknown format '.stl'"):
        load_scene_file(tmp_path / "x.stl")


def test_a_spec_lists_scene_files_and_hashes_their_content(mesh_scene, tmp_path):
    from samp.data.spec import FILE_GENERATOR, load_spec

    (tmp_path / "cell.urdf").write_text(CELL_URDF)
    raw = {"name": "mine", "train_scenes": 1, "val_scenes": 0, "trajectories_per_scene": 2,
           "scene_files": {"train": [str(mesh_scene)], "val": [str(tmp_path / "cell.urdf")]}}
    spec = load_spec(raw)
    jobs = spec.scene_jobs()
    assert [(j.index, j.split, j.generator) for j in jobs] == [(0, "train", "tabletop"), (1, "train", FILE_GENERATOR),
                                                                (2, "val", FILE_GENERATOR)]
    assert spec.num_scenes == 3
    before = spec.config_hash()
    (tmp_path / "cell.urdf").write_text(CELL_URDF.replace('0.4 0.6 0.1', '0.4 0.6 0.12'))
    assert load_spec(raw).config_hash() != before, "editing a scene file must change the dataset's config hash"
    plain = {k: v for k, v in raw.items() if k != "scene_files"}
    assert "scene_files" not in load_spec(plain).resolved(), "specs without scene files keep their old hash"
    with pytest.raises(ValueError, match="scene_files has splits \\['training'\\]"):
        load_spec({**raw, "scene_files": {"training": [str(mesh_scene)]}})
    with pytest.raises(ValueError, match="scene file 'nowhere.json' not found"):
        load_spec({**raw, "scene_files": {"train": ["nowhere.json"]}})


def test_the_benchmark_overlap_check_sees_file_scenes(mesh_scene):
    from types import SimpleNamespace

    from samp.eval.benchmark import check_unseen
    from samp.scene.files import load_scene_file

    scene = load_scene_file(mesh_scene)
    problem = SimpleNamespace(scene=scene, scene_hash=scene.content_hash())
    sections = [SimpleNamespace(name="benchmark", problems=[problem], benchmark="bench_x@0")]  # a benchmark Section
    with pytest.raises(ValueError, match="cell"):
        check_unseen(sections, {scene.content_hash()}, "mine@abc")
