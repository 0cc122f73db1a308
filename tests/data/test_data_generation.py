"""Generated datasets: collision-free trajectories by an independent check, determinism, verification,
round trips, the plain MCAP reader, three splits with evaluation problems stored apart from the
demonstrations, scene identity, legacy datasets, and clear errors on bad input."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch
import trimesh

from samp.data import (DatasetError, GenerationError, generate, load_spec, open_dataset, read_manifest, resolve_ref,
                       verify_dataset, write_dataset)
from samp.data.mcap_io import read_scene_file

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

TINY = {"name": "tiny", "robot": "panda", "seed": 7, "train_scenes": 1, "val_scenes": 1, "test_scenes": 1,
        "trajectories_per_scene": 3, "eval_problems_per_scene": 2, "generators": ["tabletop", "shelf"],
        "resolutions": [12, 16]}


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
    """Every stored trajectory (demonstrations and the expert's solutions of the evaluation problems),
    interpolated finely in joint space, keeps points on the link surfaces outside every obstacle by the
    scene's analytic SDF (not pybullet, which the expert used)."""
    folder, _ = tiny
    ds, robot = open_dataset(folder), robots["panda"]
    assert len(ds) >= 4, "the tiny spec should solve most of its 6 demonstration problems"
    solved = [(p["solution"], p["scene"]) for p in ds.eval_problems if p["success"]]
    assert len(solved) >= 4, "the tiny spec should solve most of its 6 evaluation problems"
    surface = _surface_points(robot)
    worst = np.inf
    for traj, scene_index in [*zip(ds.trajectories.numpy(), ds.traj_scene.tolist()), *solved]:
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
    for p in ds.eval_problems:
        if p["success"]:
            assert p["solution"].shape == (50, 7) and p["solution"].dtype == np.float64 and p["reason"] == ""
            np.testing.assert_array_equal(p["solution"][0], p["start"])
            np.testing.assert_array_equal(p["solution"][-1], p["goal"])
            assert p["planning_time"] > 0
        else:
            assert p["solution"] is None and p["reason"], "a failed evaluation problem without its reason"


def test_manifest_names_splits_and_counts(tiny):
    folder, root = tiny
    m = read_manifest(folder)
    assert folder == root / "tiny" / m["id"]
    counts = {k: m["counts"][k] for k in ("scenes", "train_scenes", "val_scenes", "test_scenes", "episodes",
                                          "eval_problems")}
    assert counts == {"scenes": 3, "train_scenes": 1, "val_scenes": 1, "test_scenes": 1, "episodes": 6,
                      "eval_problems": 6}, counts
    assert {s: m["splits"][s] for s in ("train", "val", "test")} == {
        "train": [m["scenes"][0]["name"]], "val": [m["scenes"][1]["name"]], "test": [m["scenes"][2]["name"]]}
    assert m["config_hash"] == load_spec(TINY).config_hash()
    assert m["robot"]["name"] == "panda" and len(m["robot"]["asset_hash"]) == 64
    assert {"git_commit", "git_dirty", "package"} <= set(m["code_version"])
    assert all(len(s["planning_time"]) == s["episodes"] for s in m["scenes"])
    assert all(len(s["eval_planning_time"]) == s["eval_problems"] for s in m["scenes"])
    jobs = load_spec(TINY).scene_jobs()
    for s, job in zip(m["scenes"], jobs):  # every scene: split, generator and seed, counts of both kinds
        assert (s["split"], s["generator"], s["seed"]) == (job.split, job.generator, job.seed)
        assert (s["episodes"], s["eval_problems"]) == ((0, 2) if job.split == "test" else (3, 2)), s
    ds = open_dataset(folder)
    assert ds.scene_split == ["train", "val", "test"] and ds.legacy_splits is False
    assert list(ds.traj_split) == [ds.scene_split[i] for i in ds.traj_scene.tolist()]
    assert 2 not in ds.traj_scene.tolist() and not [e for e in ds.episodes if e["scene"] == 2], \
        "a test scene holds no demonstrations"
    assert [(p["scene"], p["index"], p["split"]) for p in ds.eval_problems] == [
        (i, k, split) for i, split in enumerate(("train", "val", "test")) for k in range(2)]


def test_manifest_scene_hashes_are_the_decoded_scenes_content_hashes(tiny):
    folder, _ = tiny
    ds = open_dataset(folder)
    stored = [s["content_hash"] for s in read_manifest(folder)["scenes"]]
    decoded = [read_scene_file(folder / s["file"], resolutions=[]).scene.content_hash() for s in ds.manifest["scenes"]]
    assert stored == decoded == ds.scene_hashes == [scene.content_hash() for scene in ds.scenes]
    assert len(set(stored)) == 3, "three different scenes"


def test_evaluation_problems_are_stored_apart_from_the_training_data(tiny):
    """Every evaluation problem is stored (start, goal, the expert's solution), and none of it is in
    `ds.trajectories` or `ds.episodes`: compared by value, no demonstration starts or ends where an
    evaluation problem does, and no solution is a demonstration."""
    ds = open_dataset(tiny[0])
    assert len(ds.eval_problems) == 6 and len(ds.episodes) == 6
    demos = ds.trajectories.numpy()  # (N, 50, 7)
    for p in ds.eval_problems:
        start, goal = np.asarray(p["start"]), np.asarray(p["goal"])
        assert not (demos[:, 0] == start).all(axis=1).any(), f"evaluation problem {p['index']} starts a demonstration"
        assert not (demos[:, -1] == goal).all(axis=1).any(), f"evaluation problem {p['index']} ends a demonstration"
        if p["success"]:
            assert not any(np.array_equal(p["solution"], d) for d in demos)
    starts = {tuple(e["start"]) for e in ds.episodes}
    assert not starts & {tuple(p["start"]) for p in ds.eval_problems}
    assert {e["purpose"] for e in ds.episodes} == {"demonstration"}


def test_scene_identity_follows_the_namespace(tiny):
    """Scene seeds come from (seed, namespace, index): specs with different names and the same seed draw
    different scenes, unless they name the same scene_namespace."""
    from samp.scene.registry import scene_from_config

    def hashes(spec: dict) -> list[str]:
        s = load_spec(spec)
        return [scene_from_config(s.generator_config(j.generator), j.seed).content_hash() for j in s.scene_jobs()]

    ds = open_dataset(tiny[0])
    assert hashes(TINY) == ds.scene_hashes, "the spec's scenes are the dataset's scenes"
    other = hashes({**TINY, "name": "other"})
    assert not set(other) & set(ds.scene_hashes), "a spec with another name shares a scene"
    assert hashes({**TINY, "name": "other", "scene_namespace": "tiny"}) == ds.scene_hashes
    assert load_spec({**TINY, "scene_namespace": "tiny"}).config_hash() == load_spec(TINY).config_hash()


def test_grids_are_the_exact_scene_sdf(tiny):
    ds = open_dataset(tiny[0])
    for i, scene in enumerate(ds.scenes):
        for n in (12, 16):
            torch.testing.assert_close(ds.grid(i, n), scene.anchor_grid(n, cache=False), rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"n_e in \[12, 16\], not 40"):
        ds.grid(0, 40)


def test_same_spec_and_seed_give_the_same_id(tiny, tmp_path):
    """Regenerated elsewhere, by the command line planning in its own process (workers=1): byte-identical
    files, the same id."""
    import subprocess
    import sys

    spec = [f"dataset.{k}=" + (f"[{','.join(v)}]" if isinstance(v, list) and isinstance(v[0], str) else
                               str(v).replace(" ", "")) for k, v in {**TINY, "detour_share": 0.0}.items()]
    out = subprocess.run([sys.executable, "-m", "samp.data", "generate", "+dataset=quickstart", *spec,
                          f"root={tmp_path}", "workers=1", "progress=false"], capture_output=True, text=True,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    again = tmp_path / TINY["name"] / tiny[0].name
    assert again.name == tiny[0].name
    assert len(list(tiny[0].glob("*.mcap"))) == 3
    for f in sorted(tiny[0].glob("*.mcap")):
        assert (again / f.name).read_bytes() == f.read_bytes()


# A small spec whose problems all need the planner (detours): its files as the code made them when the standing
# benchmark was generated (commit 349489a), so a speed-up that changes a single planned state fails here.
PINNED = {"name": "pin", "robot": "panda", "seed": 7, "train_scenes": 1, "val_scenes": 0, "test_scenes": 1,
          "trajectories_per_scene": 4, "eval_problems_per_scene": 2, "generators": ["shelf", "tabletop"],
          "resolutions": [12], "detour_share": 0.5}
PINNED_FILES = {"scene_0000.mcap": "2df5e22599cbbb812f75a06e431945fc2fe157ebf20eb05c3f66ac1d60435187",
                "scene_0001.mcap": "f1a8cfcc26194c27ef0b3d4c5cf208752a53395f318badb2dd7954c3a17abbc0"}


def test_a_pinned_spec_gives_the_files_it_always_gave(tmp_path):
    """Same spec and seed, same bytes across code versions and machines: datasets keep their ids and contents
    (the standing benchmark's among them). A change that must alter the output changes the format version
    instead and records the new digests here. Generated from a process like a training recipe's, whose MKL
    already took this CPU's own kernels (no MKL_CBWR, an MKL solve first): its workers plan on MKL's
    CPU-independent path all the same, so the digests, pinned on another machine, hold on this one."""
    import hashlib
    import os
    import subprocess
    import sys

    code = ("import sys, torch; from samp.data.generation import generate; "
            "a = torch.randn(64, 64, dtype=torch.float64); "
            "torch.linalg.solve(a @ a.T + torch.eye(64, dtype=torch.float64), a); "
            f"print(generate({PINNED!r}, root=sys.argv[1], workers=2, progress=False))")
    env = {k: v for k, v in os.environ.items() if k != "MKL_CBWR"}
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path)], capture_output=True, text=True, env=env,
                         timeout=600)
    assert out.returncode == 0, out.stderr[-2000:]
    folder = Path(out.stdout.strip().splitlines()[-1])
    assert folder.name == "bce1d3e51215"
    digests = {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in sorted(folder.glob("*.mcap"))}
    assert digests == PINNED_FILES, "the generated files differ from those this spec has always given"


def test_a_finished_dataset_generated_again_is_found_not_replanned(tiny, capsys):
    """Generating the same spec again returns the finished dataset, says so in one line, plans nothing
    (no work folder appears, no file changes) and merging again says the same instead of "not generated"."""
    from samp.data.generation import merge, work_dir
    from samp.data.spec import load_spec

    folder, root = tiny
    before = {f.name: f.stat().st_mtime_ns for f in folder.iterdir()}
    capsys.readouterr()
    assert generate(TINY, root=root, workers=2, progress=False) == folder
    lines = [x for x in capsys.readouterr().out.splitlines() if x.strip()]
    assert lines == [f"tiny: already generated from this spec as tiny@{folder.name} ({folder}); nothing to plan or "
                     "merge"], lines
    assert not work_dir(load_spec(TINY), root).exists(), "generating again started planning"
    assert merge(TINY, root=root) == folder
    assert f"already merged into tiny@{folder.name}" in capsys.readouterr().out
    assert {f.name: f.stat().st_mtime_ns for f in folder.iterdir()} == before
    other = dict(TINY, seed=8)  # another spec of the same name is not "found"
    with pytest.raises(GenerationError, match="not generated yet"):
        merge(other, root=root)


def test_a_legacy_dataset_with_heldout_scenes_still_opens(tiny, tmp_path):
    """A dataset written before issue 17 (its second scene labelled "heldout", no evaluation problems)
    opens with "heldout" read as "val" and `legacy_splits` set; relabelled alone, it is legacy too."""
    ds = open_dataset(tiny[0])
    ds.scene_split[1] = "heldout"
    relabelled = open_dataset(write_dataset(ds, name="relabelled", root=tmp_path))
    assert read_scene_file(relabelled.path / "scene_0001.mcap", resolutions=[]).split == "heldout"
    assert relabelled.scene_split == ["train", "val", "test"] and relabelled.legacy_splits is True
    assert relabelled.scene_indices("heldout") == relabelled.scene_indices("val") == [1]
    assert relabelled.has_eval_problems and len(relabelled.eval_problems) == 6
    ds.eval_problems, ds.has_eval_problems = [], False
    legacy = open_dataset(write_dataset(ds, name="legacy", root=tmp_path))
    assert legacy.legacy_splits is True and legacy.has_eval_problems is False and legacy.eval_problems == []
    assert legacy.scene_split == ["train", "val", "test"] and list(legacy.traj_split) == list(ds.traj_split)
    assert legacy.scene_hashes == ds.scene_hashes
    assert not any(k.startswith("eval_") for s in legacy.manifest["scenes"] for k in s)
    with open(legacy.path / "scene_0000.mcap", "rb") as f:
        from mcap.reader import make_reader

        topics = {c.topic for c in make_reader(f).get_summary().channels.values()}
    assert not {"/eval/episode", "/eval/trajectory"} & topics


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
                           "/trajectory": "foxglove.JointStates", "/eval/episode": "samp.Episode",
                           "/eval/trajectory": "foxglove.JointStates", "/sdf/n12": "foxglove.VoxelGrid",
                           "/sdf/n16": "foxglove.VoxelGrid", "/tf": "foxglove.FrameTransforms",
                           "/robot": "foxglove.SceneUpdate", "/ee_path": "foxglove.SceneUpdate"}
        assert {c.compression for c in summary.chunk_indexes} == {"zstd"}
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        assert meta["samp.dataset"]["dataset"] == "tiny" and meta["samp.dataset"]["split"] == "train"
        first = next(reader.iter_decoded_messages(topics=["/trajectory"]))
        assert [j.name for j in first.decoded_message.joints] == [f"panda_joint{i}" for i in range(1, 8)]
        grid = next(reader.iter_decoded_messages(topics=["/sdf/n12"])).decoded_message
        assert (grid.row_count, grid.column_count, len(grid.data)) == (12, 12, 4 * 12**3)
        episode = json.loads(next(reader.iter_messages(topics=["/episode"]))[2].data)
        assert {"episode", "success", "reason", "start", "goal", "stats"} <= set(episode)
        assert episode["purpose"] == "demonstration"
        evaluation = [json.loads(m.data) for _, _, m in reader.iter_messages(topics=["/eval/episode"])]
        assert len(evaluation) == 2 and {e["purpose"] for e in evaluation} == {"evaluation"}
        solution = next(reader.iter_decoded_messages(topics=["/eval/trajectory"]))
        assert [j.name for j in solution.decoded_message.joints] == [f"panda_joint{i}" for i in range(1, 8)]
        last_demo = max(m.log_time for _, _, m in reader.iter_messages(topics=["/trajectory"]))
        assert solution.message.log_time > last_demo, "evaluation problems play after the demonstrations"


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
    with pytest.raises(DatasetError, match=r"format version 99; this samp reads versions \(1, 2\)"):
        open_dataset(folder)


def test_spec_without_a_valid_start_is_a_clear_error(tmp_path):
    spec = {**TINY, "name": "cramped", "train_scenes": 1, "val_scenes": 0, "test_scenes": 0,
            "generators": ["tabletop"], "expert_overrides": {"clearance": 0.6, "problems": {"start_rounds": 2, "start_batch": 64}}}
    with pytest.raises(GenerationError, match=r"scene 0 .*cannot host valid planning problems.*collision-free"):
        generate(spec, root=tmp_path, progress=False)


@pytest.mark.parametrize("bad, message", [
    ({"trajectories_per_scene": 0}, "trajectories_per_scene must be >= 1"),
    ({"generators": ["moon"]}, r"unknown scene generators \['moon'\]; available: \["),
    ({"robot": "r2d2"}, "unknown robot 'r2d2'"),
    ({"resolutions": [1]}, "resolutions must list"),
    ({"colour": "red"}, r"invalid dataset spec: .*valid keys: name, robot"),
    ({"expert_overrides": {"planner_typo": 1}}, "invalid expert config"),
    ({"heldout_scenes": 1}, r"'heldout_scenes' is retired: use val_scenes and test_scenes"),
    ({"val_scenes": -1}, r"train_scenes, val_scenes and test_scenes must be >= 0 .* got \(1, -1, 1\)"),
    ({"eval_problems_per_scene": 0}, "eval_problems_per_scene must be >= 0, and >= 1 when the spec has test scenes"),
    ({"scene_namespace": ""}, "scene_namespace must be a non-empty string or null"),
    ({"detour_share": 1.5}, r"detour_share must be in \[0, 1\], got 1.5"),
    ({"expert_overrides": {"backend": "curobo"}}, "backend 'curobo' is not implemented"),
])
def test_bad_specs_say_what_is_wrong(bad, message):
    with pytest.raises(ValueError, match=message):
        load_spec({**TINY, **bad})


def _decoded(path, topics):
    from mcap.reader import make_reader
    from mcap_protobuf.decoder import DecoderFactory

    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        return [(m.message, m.decoded_message) for m in reader.iter_decoded_messages(topics=topics)]


def test_scene_files_play_in_foxglove_with_the_arm_moving(tiny, robots):
    """Each waypoint's /tf holds every link's pose from forward kinematics (checked against the robot's own
    FK of the stored joint angles), at the waypoint's time; a trajectory lasts its joint-space length at
    the nominal joint speed; the robot's link meshes and the end-effector path are there; voxel cells are
    centred on the anchors; mesh obstacles are embedded."""
    from scipy.spatial.transform import Rotation

    from samp.data import foxglove as fox

    robot, path = robots["panda"], tiny[0] / "scene_0000.mcap"
    states = _decoded(path, ["/trajectory"])
    tfs = {m.log_time: msg for m, msg in _decoded(path, ["/tf"])}
    assert len(tfs) == len(states) + len(_decoded(path, ["/eval/trajectory"]))  # one per waypoint
    q = np.array([[j.position for j in msg.joints] for _, msg in states])
    fk = robot.fk(torch.as_tensor(q, dtype=torch.float64))
    for (meta, _), k in zip(states, range(len(states))):
        tf = {t.child_frame_id: t for t in tfs[meta.log_time].transforms}
        assert set(robot.link_meshes) <= set(tf), sorted(tf)
        for name in robot.link_meshes:
            t, T = tf[name], fk[name][k].numpy()
            assert t.parent_frame_id == "base"
            np.testing.assert_allclose([t.translation.x, t.translation.y, t.translation.z], T[:3, 3], atol=1e-9)
            R = Rotation.from_quat([t.rotation.x, t.rotation.y, t.rotation.z, t.rotation.w]).as_matrix()
            np.testing.assert_allclose(R, T[:3, :3], atol=1e-9)
    # timing: the first trajectory, from its waypoints alone
    first = [i for i, (m, _) in enumerate(states) if m.sequence == 0]
    traj = q[first[0]:first[1]]
    times = np.array([m.log_time for m, _ in states[first[0]:first[1]]])
    length = np.linalg.norm(np.diff(traj, axis=0), axis=1).sum()
    assert np.all(np.diff(times) >= 0) and times[0] == 0
    assert abs((times[-1] - times[0]) / 1e9 - max(length / fox.JOINT_SPEED, fox.MIN_DURATION)) < 1e-6
    assert states[first[1]][0].log_time >= times[-1] + fox.GAP * 1e9  # the next one starts after a pause
    (robot_msg,) = _decoded(path, ["/robot"])
    assert {e.frame_id for e in robot_msg[1].entities} == set(robot.link_meshes)
    assert all(e.models[0].data[:4] == b"glTF" for e in robot_msg[1].entities)
    paths = _decoded(path, ["/ee_path"])
    ee = fk[robot.ee_link][:, :3, 3].numpy()
    pts = np.array([[p.x, p.y, p.z] for p in paths[0][1].entities[0].lines[0].points])
    np.testing.assert_allclose(pts, ee[first[0]:first[1]], atol=1e-9)
    # voxel cells centred on the anchors: cell i's centre is pose + (i + 1/2) * cell_size = lo + i * spacing
    ds = open_dataset(tiny[0])
    (_, grid), = _decoded(path, ["/sdf/n12"])
    lo, hi = np.asarray(ds.scenes[0].bounds[0]), np.asarray(ds.scenes[0].bounds[1])
    spacing = (hi - lo) / 11
    origin = np.array([grid.pose.position.x, grid.pose.position.y, grid.pose.position.z])
    np.testing.assert_allclose(origin + 0.5 * spacing, lo, atol=1e-12)
    np.testing.assert_allclose(origin + 11.5 * spacing, hi, atol=1e-12)


def test_format_1_scene_files_keep_their_layout_and_read_the_same(tiny, tmp_path):
    """A dataset of the first scene-file format (ids made before) is rewritten byte for byte in its own
    layout, and reads back to the same trajectories as the current format."""
    ds = open_dataset(tiny[0])
    for meta in ds.metadata:
        meta["format_version"] = "1"
    old = open_dataset(write_dataset(ds, name="format1", root=tmp_path))
    again = write_dataset(old, name="format1b", root=tmp_path)
    for f in sorted(old.path.glob("*.mcap")):
        assert (again / f.name).read_bytes() == f.read_bytes()
    topics = {m.channel_id for m, _ in _decoded(old.path / "scene_0000.mcap", ["/tf"])}
    assert topics == set(), "format 1 files have no /tf"
    times = [m.log_time for m, _ in _decoded(old.path / "scene_0000.mcap", ["/trajectory"])]
    assert times[:3] == [0, 1, 2]  # waypoint t of episode 0 at t ns, as format 1 wrote them
    np.testing.assert_array_equal(old.trajectories.numpy(), open_dataset(tiny[0]).trajectories.numpy())
    assert len(old.eval_problems) == len(open_dataset(tiny[0]).eval_problems)


def test_every_dataset_has_a_card_outside_its_id(tiny, tmp_path):
    """CARD.md says what the dataset is (counts, splits, how to open and verify it), beside the manifest; it is
    not a hashed data file, so a dataset with its card still verifies and its id is the data's alone."""
    folder = tiny[0]
    card = (folder / "CARD.md").read_text()
    manifest = read_manifest(folder)
    assert f"# Dataset card: tiny@{manifest['id']}" in card
    for scene in manifest["splits"]["val"]:
        assert scene in card
    assert f"{manifest['counts']['trajectories']} expert trajectories" in card
    assert "CARD.md" not in manifest["files"] and verify_dataset(folder) == []
