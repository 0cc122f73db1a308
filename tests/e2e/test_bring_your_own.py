"""The "Bring your own" walk-through (docs/bring-your-own.md), shrunk, from an installed wheel.

A wheel is built from a copy of the repository's tracked files and installed into a fresh virtual environment
outside the clone (its dependencies are those of the test's own environment, reached through a `.pth`
path: installing torch and the rest again would take minutes and the network). Then, in a temporary
project folder: a robot added from its URDF (a copy of pybullet_data's Panda under a name of its own, so
that its robot SDF is trained here), two scenes made of mesh files, demonstrations recorded "elsewhere"
(planned here and densified, plus one that passes through an obstacle), imported; a user experiment trained
twice, evaluated again and compared, all through the console scripts. Nothing may be written inside the clone or into
site-packages.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import sysconfig
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]

SCENE = {"obstacles": [{"kind": "box", "name": "table", "size": [1.2, 1.6, 0.04], "pose": {"position": [0.5, 0, -0.02]}},
                       {"kind": "mesh", "name": "crate", "path": "crate.obj", "pose": {"position": [0.55, 0.4, 0.15]}}],
         "target": {"kind": "box", "name": "target", "size": [0.04, 0.04, 0.08], "pose": {"position": [0.5, -0.2, 0.04]}}}
EXPERIMENT = """# @package _global_
# My policy on the demonstrations I recorded in my cells.
defaults:
  - quickstart
  - override /robot: myarm
name: my_policy
datamodule:
  dataset: mydemos
build_missing:
  dataset: false
evaluation:
  benchmark: null
"""
# Shrunk as tests/test_readme.py shrinks training: a tiny robot SDF, a few batches, one problem, no benchmark.
TINY = ("datamodule.n_e=16 datamodule.val_samples=50 trainer.max_epochs=1 +trainer.limit_train_batches=2 "
        "trainer.enable_progress_bar=false evaluation.problems=1 evaluation.benchmark=null "
        "\"build_missing.robot_sdf_overrides=['robot_sdf_samples=tiny','trainer.max_steps=40','robot_sdf_eval=tiny']\"")
RECORD = """
import sys
import numpy as np
from samp.expert.planner import plan_scene
from samp.expert.trajectory import resample
from samp.robot import load_robot
from samp.scene.files import load_scene_file
robot = load_robot("myarm")
demos, scene_of = [], []
for k, name in enumerate(["scenes/cell_a.json", "scenes/cell_b.json"]):
    results = plan_scene(robot, load_scene_file("conf/" + name), 3, seed=k)
    for r in results:
        if r.success:
            demos.append(resample(r.trajectory, 120)); scene_of.append(k)
home = np.array(robot.cfg.home)
demos.append(np.linspace(home, [0, 1.5, 0, -1.0, 0, 1.571, 0.785], 80)); scene_of.append(0)  # 10 cm into the table
np.savez("demos.npz", joint_positions=np.concatenate(demos), episode_ends=np.cumsum([len(d) for d in demos]),
         scenes=np.array(["scenes/cell_a.json", "scenes/cell_b.json"]), episode_scene=np.array(scene_of))
print(len(demos))
"""


def _tree(folder: Path) -> set[str]:
    """Every path under `folder` but git's own store and caches (other worktrees may commit meanwhile)."""
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*")
            if "__pycache__" not in p.parts and p.relative_to(folder).parts[0] != ".git"}


def _run(cmd: str, cwd: Path, env: dict, timeout: int = 900) -> str:
    out = subprocess.run(cmd, shell=True, cwd=cwd, env=env, capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, f"{cmd}\nstdout:\n{out.stdout[-3000:]}\nstderr:\n{out.stderr[-3000:]}"
    return out.stdout


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """(venv bin folder, environment) of a fresh virtual environment holding samp's built wheel."""
    tmp = tmp_path_factory.mktemp("wheel")
    src = tmp / "src"
    files = subprocess.run(["git", "ls-files", "-z"], cwd=REPO, capture_output=True, text=True, check=True).stdout
    for rel in filter(None, files.split("\0")):
        if (REPO / rel).is_file():
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / rel, src / rel)
    _run(f"{sys.executable} -m build --wheel --no-isolation --outdir {tmp / 'dist'} {src}", tmp, dict(os.environ))
    wheel = next((tmp / "dist").glob("samp-*.whl"))
    venv = tmp / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True)
    _run(f"{sys.executable} -m pip --python {venv / 'bin' / 'python'} install -q --no-deps {wheel}", tmp, dict(os.environ))
    site = Path(subprocess.run([str(venv / "bin" / "python"), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                               capture_output=True, text=True, check=True).stdout.strip())
    (site / "zz_samp_test_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    env = {k: v for k, v in os.environ.items() if not k.startswith("SAMP_")}
    env.update(PATH=f"{venv / 'bin'}:{env['PATH']}", HOME=str(tmp / "home"), OMP_NUM_THREADS="1",
               MPLBACKEND="Agg")
    return venv / "bin", env, site


@pytest.mark.slow
def test_the_wheel_carries_configs_and_console_scripts(installed, tmp_path):
    bin_dir, env, site = installed
    where = _run("python -c 'import samp, samp.paths as p; print(samp.__file__); print(p.conf_dir())'", tmp_path, env)
    assert str(site) in where.splitlines()[0], f"samp imported from elsewhere: {where}"
    assert (site / "samp" / "_conf" / "experiment" / "quickstart.yaml").is_file()
    for script in ("samp-train", "samp-eval", "samp-data", "samp-runs", "samp-robot", "samp-scene"):
        assert (bin_dir / script).is_file(), script
    assert "experiments (experiment=NAME" in _run("samp-train --help", tmp_path, env)


@pytest.mark.slow
def test_bring_your_own_walk_through(installed, tmp_path):
    import trimesh

    bin_dir, env, site = installed
    clone_before, site_before = _tree(REPO), _tree(site)
    project = tmp_path / "myproject"
    (project / "conf" / "scenes").mkdir(parents=True)
    (project / "conf" / "experiment").mkdir()
    trimesh.creation.box((0.3, 0.3, 0.3)).export(project / "conf" / "scenes" / "crate.obj")
    (project / "conf" / "scenes" / "cell_a.json").write_text(json.dumps(SCENE))
    other = json.loads(json.dumps(SCENE))
    other["obstacles"][1]["pose"]["position"] = [0.35, -0.45, 0.15]
    (project / "conf" / "scenes" / "cell_b.json").write_text(json.dumps(other))
    (project / "conf" / "experiment" / "my_policy.yaml").write_text(EXPERIMENT)
    import pybullet_data

    shutil.copytree(Path(pybullet_data.getDataPath()) / "franka_panda", project / "robots" / "franka_panda")
    env = {**env, "SAMP_CONFIG_PATH": str(project / "conf")}
    out = _run("samp-robot add urdf=robots/franka_panda/panda.urdf name=myarm", project, env)
    assert (project / "conf" / "robot" / "myarm.yaml").is_file(), out
    assert "samp.train experiment=robot_sdf_quick robot=myarm" in out, out

    (project / "record.py").write_text(RECORD)
    count = int(_run("python record.py", project, env).strip().splitlines()[-1])
    out = _run("samp-data import source=demos.npz name=mydemos robot=myarm resolutions=16 eval_problems=1 "
               "progress=false",
               project, env)
    assert f"imported {count - 1} of {count} trajectories (1 refused)" in out, out
    assert "demos.npz#" in out and "obstacle 'table'" in out and "recorded step" in out, out
    manifest = json.loads(next((project / "datasets" / "mydemos").glob("*/manifest.json")).read_text())
    assert manifest["parents"][0].startswith("sha256:") and manifest["counts"]["failures"] == 1

    _run(f"samp-train experiment=my_policy {TINY}", project, env)
    _run(f"samp-train experiment=my_policy seed=1 {TINY}", project, env)
    runs = sorted((project / "runs" / "my_policy").glob("*/run.json"))
    assert len(runs) == 2, runs
    assert list((project / "runs" / "robot_sdf_myarm_quick").glob("*/run.json")), "the robot's own SDF was not built"
    record = json.loads(runs[0].read_text())
    assert f"mydemos@{manifest['id']}" in json.dumps(record), "the run must name the imported dataset it trained on"
    _run(f"samp-eval run={runs[0].parent} problems=1 splits=[val] benchmark=null record=false overwrite=true",
         project, env)
    compared = _run(f"samp-runs compare {runs[0].parent} {runs[1].parent}", project, env)
    assert runs[0].parent.name in compared and runs[1].parent.name in compared

    assert _tree(REPO) == clone_before, sorted(_tree(REPO) ^ clone_before)[:10]
    assert _tree(site) == site_before, sorted(_tree(site) ^ site_before)[:10]
