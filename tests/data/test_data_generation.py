"""Generated datasets: collision-free trajectories by an independent check, determinism, verification,
round trips, the plain MCAP reader, and clear errors on bad input."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import torch
import trimesh

from samp.data import (DatasetError, GenerationError, generate, load_spec, open_dataset, read_manifest, resolve_ref,
                       verify_dataset, write_dataset)
from samp.data.mcap_io import read_scene_file

TINY = {"name": "tiny", "robot": "panda", "seed": 7, "train_scenes": 1, "heldout_scenes": 1,
        "trajectories_per_scene": 3, "generators": ["tabletop", "shelf"], "resolutions": [12, 16]}


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    root = tmp_path_factory.mktemp("datasets")
    return generate(TINY, root=root, progress=False), root


def _interpolate(traj: np.ndarray, step: float) -> np.ndarray:
    """Every segment of (W, n) at joint-space steps no longer than `step` radians, waypoints included."""
    parts = [traj[:1]]
    for a, b in zip(traj[:-1], traj[1:]):
        k = max(1, int(np.ceil(np.abs(b - a).max() / step)))
        parts.append(a + np.linspace(0, 1, k + 1)[1:, None] * (b - a))
    return np.concatenate(parts)


def _surface_points(robot, per_link: int = 250) -> dict[str, torch.Tensor]:
    """Points on the exact surface of every moving link (link frame), independent of the robot points."""
    out = {}
    for name in robot.link_names:
        if name == robot.base_link:  # stands on the table, as in World: never checked against obstacles
            continue
        mesh: trimesh.Trimesh = robot.link_meshes[name]
        pts, _ = trimesh.sample.sample_surface(mesh, per_link, seed=0)
        out[name] = torch.as_tensor(np.asarray(pts), dtype=torch.float64)
    return out


def test_trajectories_clear_by_an_independent_check(tiny, robots):
    """Every stored trajectory, interpolated finely in joint space, keeps points on the link surfaces
    outside every obstacle by the scene's analytic SDF (not pybullet, which the expert used)."""
    folder, _ = tiny
    ds, robot = open_dataset(folder), robots["panda"]
    assert len(ds) >= 4, "the tiny spec should solve most of its 6 problems"
    surface = _surface_points(robot)
    worst = np.inf
    for traj, scene_index in zip(ds.trajectories.numpy(), ds.traj_scene.tolist()):
        dense = _interpolate(traj, 0.008)  # finer than the expert's own check (0.02 rad, Euclidean)
        poses = robot.fk(torch.from_numpy(dense))
        for name, pts in surface.items():
            world = pts @ poses[name][:, :3, :3].transpose(1, 2) + poses[name][:, None, :3, 3]
            d = ds.scenes[scene_index].sdf(world.reshape(-1, 3))
            worst = min(worst, float(d.min()))
    assert worst > 0.0, f"a stored trajectory penetrates an obstacle by {-worst * 1000:.2f} mm"


def test_trajectories_start_and_end_at_their_problem(tiny):
    ds = open_dataset(tiny[0])
    solved = [e for e in ds.episodes if e["success"]]
    assert len(solved) == len(ds)
    assert ds.trajectories.shape[1:] == (50, 7)
    for traj, e in zip(ds.trajectories.numpy(), solved):
        np.testing.assert_array_equal(traj[0], e["start"])
        np.testing.assert_array_equal(traj[-1], e["goal"])
    failed = [e for e in ds.episodes if not e["success"]]
    assert all(e["reason"] for e in failed), "a failure without its reason"


def test_manifest_names_splits_and_counts(tiny):
    folder, root = tiny
    m = read_manifest(folder)
    assert folder == root / "tiny" / m["id"]
    assert m["counts"]["scenes"] == 2 and m["counts"]["episodes"] == 6
    assert m["splits"]["heldout"] == [m["scenes"][1]["name"]] and m["splits"]["train"] == [m["scenes"][0]["name"]]
    assert m["config_hash"] == load_spec(TINY).config_hash()
    assert m["robot"]["name"] == "panda" and len(m["robot"]["asset_hash"]) == 64
    assert {"git_commit", "git_dirty", "package"} <= set(m["code_version"])
    assert all(len(s["planning_time"]) == s["episodes"] for s in m["scenes"])
    ds = open_dataset(folder)
    assert ds.scene_split == ["train", "heldout"]
    assert list(ds.traj_split) == [ds.scene_split[i] for i in ds.traj_scene.tolist()]


def test_grids_are_the_exact_scene_sdf(tiny):
    ds = open_dataset(tiny[0])
    for i, scene in enumerate(ds.scenes):
        for n in (12, 16):
            torch.testing.assert_close(ds.grid(i, n), scene.anchor_grid(n, cache=False), rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"n_e in \[12, 16\], not 40"):
        ds.grid(0, 40)


def test_same_spec_and_seed_give_the_same_id(tiny, tmp_path):
    """Regenerated elsewhere with two worker processes: byte-identical files, the same id."""
    again = generate(TINY, root=tmp_path, workers=2, progress=False)
    assert again.name == tiny[0].name
    for f in sorted(tiny[0].glob("*.mcap")):
        assert (again / f.name).read_bytes() == f.read_bytes()


def test_write_read_write_is_identical(tiny, tmp_path):
    ds = open_dataset(tiny[0])
    copy = write_dataset(ds, root=tmp_path)
    assert copy.name == ds.id
    assert read_manifest(copy)["parents"] == [f"tiny@{ds.id}"]
    again = write_dataset(open_dataset(copy), root=tmp_path / "again")
    for f in sorted(tiny[0].glob("*.mcap")):
        assert (copy / f.name).read_bytes() == f.read_bytes() == (again / f.name).read_bytes()


def test_verify_names_a_changed_file(tiny, tmp_path):
    folder = shutil.copytree(tiny[0], tmp_path / "tiny" / tiny[0].name)
    assert verify_dataset(folder) == []
    target = folder / "scene_0001.mcap"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x01  # one bit of one byte, same size
    target.write_bytes(bytes(data))
    problems = verify_dataset(folder)
    assert len(problems) == 1 and problems[0].startswith("scene_0001.mcap: sha256 expected")


def test_plain_mcap_reader_and_foxglove_schemas(tiny):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    path = tiny[0] / "scene_0000.mcap"
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        schemas = {ch.topic: summary.schemas[ch.schema_id].name for ch in summary.channels.values()}
        assert schemas == {"/scene": "foxglove.SceneUpdate", "/scene/spec": "samp.SceneSpec", "/episode": "samp.Episode",
                           "/trajectory": "foxglove.JointStates", "/sdf/n12": "foxglove.VoxelGrid",
                           "/sdf/n16": "foxglove.VoxelGrid"}
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        assert meta["samp.dataset"]["dataset"] == "tiny" and meta["samp.dataset"]["split"] == "train"
        first = next(reader.iter_decoded_messages(topics=["/trajectory"]))
        assert [j.name for j in first.decoded_message.joints] == [f"panda_joint{i}" for i in range(1, 8)]
        grid = next(reader.iter_decoded_messages(topics=["/sdf/n12"])).decoded_message
        assert (grid.row_count, grid.column_count, len(grid.data)) == (12, 12, 4 * 12**3)
        episode = json.loads(next(reader.iter_messages(topics=["/episode"]))[2].data)
        assert {"episode", "success", "reason", "start", "goal", "stats"} <= set(episode)


def test_unknown_reference_lists_the_available_ones(tiny):
    _, root = tiny
    with pytest.raises(DatasetError, match=r"no dataset 'nope'.*available: tiny@"):
        resolve_ref("nope", root)
    assert resolve_ref(f"tiny@{tiny[0].name[:5]}", root) == tiny[0]


def test_truncated_file_and_unknown_format_are_clear_errors(tiny, tmp_path):
    folder = shutil.copytree(tiny[0], tmp_path / "tiny" / tiny[0].name)
    target = folder / "scene_0000.mcap"
    target.write_bytes(target.read_bytes()[:-200])
    with pytest.raises(DatasetError, match=r"scene_0000.mcap has \d+ bytes, the manifest says \d+; it is truncated"):
        open_dataset(folder)
    with pytest.raises(ValueError, match="may be truncated"):
        read_scene_file(target)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["format_version"] = 99
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="format version 99; this samp reads version 1"):
        open_dataset(folder)


def test_spec_without_a_valid_start_is_a_clear_error(tmp_path):
    spec = {**TINY, "name": "cramped", "train_scenes": 1, "heldout_scenes": 0, "generators": ["tabletop"],
            "expert_overrides": {"clearance": 0.6, "problems": {"start_rounds": 2, "start_batch": 64}}}
    with pytest.raises(GenerationError, match=r"scene 0 .*cannot host valid planning problems.*collision-free"):
        generate(spec, root=tmp_path, progress=False)


@pytest.mark.parametrize("bad, message", [
    ({"trajectories_per_scene": 0}, "trajectories_per_scene must be >= 1"),
    ({"generators": ["moon"]}, r"unknown scene generators \['moon'\]; available: \["),
    ({"robot": "r2d2"}, "unknown robot 'r2d2'"),
    ({"resolutions": [1]}, "resolutions must list"),
    ({"colour": "red"}, r"invalid dataset spec: .*valid keys: name, robot"),
    ({"expert_overrides": {"planner_typo": 1}}, "invalid expert config"),
])
def test_bad_specs_say_what_is_wrong(bad, message):
    with pytest.raises(ValueError, match=message):
        load_spec({**TINY, **bad})
