"""`samp.data import`: demonstrations recorded elsewhere (.npz, HDF5, a LeRobot folder) as a samp dataset.

Oracles: a straight joint-space motion recorded at uneven steps must come out as the evenly spaced line
between its ends (arc-length resampling, computed here by `np.linspace`); the three formats holding the
same numbers give the same trajectories; the manifest's parent is the source file's sha256 by hashlib;
and the refusals are trajectories built to fail one check each (through the table, a jump, beyond a limit).
"""

from __future__ import annotations

import hashlib
import json

import numpy as np
import pytest

TABLE = {"obstacles": [{"kind": "box", "name": "table", "size": [1.2, 1.6, 0.04], "pose": {"position": [0.5, 0, -0.02]}}],
         "target": {"kind": "box", "name": "target", "size": [0.04, 0.04, 0.08], "pose": {"position": [0.5, -0.2, 0.04]}}}
HOME = np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 0.785])
AWAY = np.array([0.6, -0.5, 0.2, -2.0, 0.1, 1.8, 0.5])
INTO_TABLE = np.array([0.0, 1.5, 0.0, -1.0, 0.0, 1.571, 0.785])


def _uneven_line(a, b, steps=40, seed=0):
    """(steps, 7): a to b along the straight line, at uneven spacing."""
    t = np.sort(np.random.default_rng(seed).uniform(0, 1, steps - 2))
    return a + np.concatenate([[0.0], t, [1.0]])[:, None] * (b - a)


@pytest.fixture
def scene_file(tmp_path):
    path = tmp_path / "table.json"
    path.write_text(json.dumps(TABLE))
    return str(path)


def _config(name, **kw):
    from samp.data.importing import ImportConfig

    return ImportConfig(name=name, resolutions=(8,), eval_problems_per_scene=0, **kw)


def test_npz_import_resamples_checks_and_records_its_source(tmp_path, scene_file):
    from samp.data import open_dataset
    from samp.data.importing import import_dataset

    good = [_uneven_line(HOME, AWAY, seed=s) for s in range(3)]
    jump = _uneven_line(HOME, AWAY, seed=9)
    jump[20:, 2] += 0.8  # joint 3 jumps 0.8 rad between two recorded steps
    beyond = _uneven_line(HOME, np.array([0.0, -0.785, 0.0, -2.356, 0.0, 1.571, 3.2]))  # joint 7's limit is 2.8973
    through = _uneven_line(HOME, INTO_TABLE)
    episodes = [*good, jump, beyond, through]
    source = tmp_path / "demos.npz"
    np.savez(source, joint_positions=np.concatenate(episodes), episode_ends=np.cumsum([len(e) for e in episodes]),
             scene=np.array([scene_file]))
    folder, summary = import_dataset([source], _config("imp"), root=tmp_path / "datasets", progress=False)
    assert (summary["kept"], summary["refused"]) == (3, 3), summary
    reasons = "\n".join(summary["reasons"])
    assert "demos.npz#3" in reasons and "rad in panda_joint3 between steps 19 and 20" in reasons, reasons
    assert "demos.npz#4" in reasons and "panda_joint7 at" in reasons and "outside its limits" in reasons, reasons
    assert "demos.npz#5" in reasons and "passes through obstacle 'table'" in reasons and "at recorded step" in reasons, \
        reasons
    ds = open_dataset(folder)
    assert len(ds) == 3 and ds.manifest["counts"]["failures"] == 3
    expected = np.linspace(HOME, AWAY, ds.trajectories.shape[1])
    assert np.abs(ds.trajectories.numpy() - expected).max() < 1e-9
    assert ds.manifest["parents"] == [f"sha256:{hashlib.sha256(source.read_bytes()).hexdigest()} demos.npz"]
    refused = [e for e in ds.episodes if not e["success"]]
    assert [e["stats"]["source"] for e in refused] == ["demos.npz#3", "demos.npz#4", "demos.npz#5"]


def test_hdf5_and_lerobot_give_the_same_trajectories(tmp_path, scene_file):
    import h5py
    import pyarrow as pa
    import pyarrow.parquet as pq

    from samp.data import open_dataset
    from samp.data.importing import import_dataset
    from samp.robot import load_robot

    episodes = [_uneven_line(HOME, AWAY, seed=s) for s in range(2)]
    with h5py.File(tmp_path / "demos.h5", "w") as f:
        f["joint_positions"] = np.stack(episodes)
        f["scene"] = scene_file
    names = load_robot("panda").joint_names
    # LeRobot: the state holds the fingers first and the arm joints reversed; names say which is which
    lerobot = tmp_path / "lerobot"
    (lerobot / "meta").mkdir(parents=True)
    (lerobot / "data" / "chunk-000").mkdir(parents=True)
    order = ["finger_a", "finger_b", *reversed(names)]
    (lerobot / "meta" / "info.json").write_text(json.dumps(
        {"features": {"observation.state": {"dtype": "float32", "shape": [9], "names": order}}}))
    for k, e in enumerate(episodes):
        state = np.concatenate([np.full((len(e), 2), 0.04), e[:, ::-1]], axis=1)
        frames = np.random.default_rng(k).permutation(len(e))  # rows out of order: frame_index decides
        pq.write_table(pa.table({"observation.state": [state[i].tolist() for i in frames],
                                 "episode_index": [k] * len(e), "frame_index": frames.tolist(),
                                 "timestamp": (frames / 30.0).tolist()}),
                       lerobot / "data" / "chunk-000" / f"episode_{k:06d}.parquet")
    datasets = tmp_path / "datasets"
    h5 = open_dataset(import_dataset([tmp_path / "demos.h5"], _config("h5"), datasets, progress=False)[0])
    lr = open_dataset(import_dataset([lerobot], _config("lr", scene=scene_file), datasets, progress=False)[0])
    assert len(h5) == len(lr) == 2
    assert np.abs(h5.trajectories.numpy() - lr.trajectories.numpy()).max() < 1e-6  # LeRobot's float32 state
    assert h5.scene_hashes == lr.scene_hashes


def test_bad_sources_are_refused_clearly(tmp_path, scene_file):
    from samp.data.importing import import_dataset

    np.savez(tmp_path / "nokey.npz", q=np.zeros((2, 5, 7)))
    with pytest.raises(ValueError, match=r"nokey.npz: no `joint_positions` array \(keys: \['q'\]\)"):
        import_dataset([tmp_path / "nokey.npz"], _config("x"), tmp_path / "d", progress=False)
    np.savez(tmp_path / "noscene.npz", joint_positions=np.zeros((2, 5, 7)))
    with pytest.raises(ValueError, match="say which scene"):
        import_dataset([tmp_path / "noscene.npz"], _config("x"), tmp_path / "d", progress=False)
    np.savez(tmp_path / "narrow.npz", joint_positions=np.zeros((2, 5, 6)), scene=np.array([scene_file]))
    with pytest.raises(ValueError, match="6 columns, but robot 'panda' has 7 joints"):
        import_dataset([tmp_path / "narrow.npz"], _config("x"), tmp_path / "d", progress=False)
    np.savez(tmp_path / "pickled.npz", joint_positions=np.array([np.zeros((5, 7)), np.zeros((6, 7))], dtype=object),
             scene=np.array([scene_file]))
    with pytest.raises(ValueError, match="pickled.npz"):
        import_dataset([tmp_path / "pickled.npz"], _config("x"), tmp_path / "d", progress=False)
    (tmp_path / "broken.npz").write_bytes(b"PK\x03\x04 not really a zip")
    with pytest.raises(ValueError, match="broken.npz is not a readable .npz"):
        import_dataset([tmp_path / "broken.npz"], _config("x"), tmp_path / "d", progress=False)
    assert not any((tmp_path / "d").rglob("manifest.json")), "a refused import must publish nothing"


def test_progress_is_not_drawn_into_a_redirected_log(tmp_path, scene_file, capfd):
    """With progress on (the command's default) and stderr not a terminal, no bar frames (`\\r`) reach it."""
    from samp.data.importing import import_dataset

    np.savez(tmp_path / "demos.npz", joint_positions=_uneven_line(HOME, AWAY)[None], scene=np.array([scene_file]))
    import_dataset([tmp_path / "demos.npz"], _config("redirected"), root=tmp_path / "datasets", progress=True)
    err = capfd.readouterr().err
    assert "\r" not in err and "import redirected" not in err, f"progress frames in a redirected stderr: {err!r}"


@pytest.mark.slow
def test_the_import_command_prints_its_summary(tmp_path, scene_file):
    """The documented command, in a folder of its own: kept and refused counted, the refusal explained."""
    import os
    import subprocess
    import sys

    episodes = [_uneven_line(HOME, AWAY), _uneven_line(HOME, INTO_TABLE)]
    np.savez(tmp_path / "demos.npz", joint_positions=np.stack(episodes))
    env = {**os.environ, "SAMP_DATASETS_DIR": str(tmp_path / "datasets"), "OMP_NUM_THREADS": "1"}
    cmd = f"python -m samp.data import source=demos.npz name=mydemos scene={scene_file} resolutions=8 eval_problems=0"
    out = subprocess.run([sys.executable, *cmd.split()[1:], "progress=false"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr
    assert "imported 1 of 2 trajectories (1 refused)" in out.stdout and "demos.npz#1" in out.stdout, out.stdout
    assert "dataset mydemos@" in out.stdout
    out = subprocess.run([sys.executable, "-m", "samp.data", "import", "source=demos.npz"], cwd=tmp_path, env=env,
                         capture_output=True, text=True, timeout=300)
    assert out.returncode == 2 and "import needs name=" in out.stderr, out.stderr
