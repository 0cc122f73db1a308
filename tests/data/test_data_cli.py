"""`python -m samp.data`: a killed generation resumes without redoing finished scenes; ls, show, verify,
inspect and merge on the result; bad input exits 2 with a clear message."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys

import pytest

from samp.data.generation import work_dir
from samp.data.spec import load_spec

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

OVERRIDES = ["+dataset=quickstart", "dataset.name=resumed", "dataset.train_scenes=2", "dataset.val_scenes=1",
             "dataset.trajectories_per_scene=3", "dataset.eval_problems_per_scene=1", "dataset.generators=[tabletop]",
             "dataset.resolutions=[8]"]
SPEC = {"name": "resumed", "train_scenes": 2, "val_scenes": 1, "trajectories_per_scene": 3, "eval_problems_per_scene": 1,
        "generators": ["tabletop"], "resolutions": [8]}


def _cmd(*args: str) -> list[str]:
    return [sys.executable, "-m", "samp.data", *args]


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run(_cmd(*args), capture_output=True, text=True, timeout=600)


# `python -m samp.data` with `run_scene` wrapped so that the process stops itself (SIGSTOP) once its first
# scene file is written: the test then kills it at exactly that point. Watching for the file from outside
# was a race: on a loaded machine the generation could finish more scenes, or all of them, before the kill.
STOP_AFTER_FIRST_SCENE = """
import os, runpy, signal, sys
import samp.data.generation as generation

run_scene = generation.run_scene

def first_then_stop(*args, **kwargs):
    record = run_scene(*args, **kwargs)
    os.kill(os.getpid(), signal.SIGSTOP)
    return record

generation.run_scene = first_then_stop
sys.argv = ["samp.data", *sys.argv[1:]]
runpy.run_module("samp.data", run_name="__main__", alter_sys=True)
"""


@pytest.fixture(scope="module")
def resumed(tmp_path_factory):
    """Generate, kill the process right after its first scene file is written, generate again."""
    root = tmp_path_factory.mktemp("datasets")
    work = work_dir(load_spec({**load_spec("quickstart").__dict__, **SPEC}), root)
    proc = subprocess.Popen([sys.executable, "-c", STOP_AFTER_FIRST_SCENE, "generate", *OVERRIDES, f"root={root}",
                             "progress=false"], stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    _, status = os.waitpid(proc.pid, os.WUNTRACED)  # returns when the process stops itself (or ends)
    assert os.WIFSTOPPED(status), f"generation ended (status {status}) instead of stopping after its first scene"
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = sorted(p.name for p in work.glob("scene_*.mcap"))
    inodes = {name: os.stat(work / name).st_ino for name in done}
    result = _run("generate", *OVERRIDES, f"root={root}", "progress=false")
    return root, done, inodes, result


def test_killed_generation_resumes_without_redoing_finished_scenes(resumed):
    root, done, inodes, result = resumed
    assert result.returncode == 0, result.stderr
    assert done == ["scene_0000.mcap"], done
    assert "resuming, 1 of 3 scenes already done" in result.stdout
    assert "3 scenes (2 train, 1 val, 0 test), " in result.stdout and " 3 evaluation problems (" in result.stdout
    (folder,) = [p for p in (root / "resumed").iterdir() if not p.name.startswith(".")]
    for name in done:  # merged by hard link: the very file the killed run wrote
        assert os.stat(folder / name).st_ino == inodes[name]
    assert not (root / "resumed" / ".work").exists(), "the work folder is removed after the merge"
    assert not list((root / "resumed").glob(".tmp-*"))


def test_ls_show_verify_inspect(resumed):
    root = resumed[0]
    ls = _run("ls", f"root={root}")
    assert ls.returncode == 0 and re.search(r"resumed@[0-9a-f]{12}\s", ls.stdout), ls.stdout
    ident = re.search(r"resumed@([0-9a-f]{12})", ls.stdout).group(1)
    show = _run("show", f"resumed@{ident[:6]}", f"root={root}")
    assert show.returncode == 0 and f'"id": "{ident}"' in show.stdout and '"val": [' in show.stdout
    assert '"eval_problems": 3' in show.stdout and '"test_scenes": 0' in show.stdout
    verify = _run("verify", "resumed", f"root={root}")
    assert verify.returncode == 0 and "every file matches" in verify.stdout
    inspect = _run("inspect", "resumed", f"root={root}")
    assert inspect.returncode == 0, inspect.stderr
    for text in ("foxglove.JointStates", "foxglove.VoxelGrid", "foxglove.SceneUpdate", "success rate per generator",
                 "/eval/episode", "/eval/trajectory", "3 scenes (2 train, 1 val, 0 test)"):
        assert text in inspect.stdout, text


def test_verify_cli_names_the_changed_file(resumed):
    root = resumed[0]
    (folder,) = [p for p in (root / "resumed").iterdir() if not p.name.startswith(".")]
    target = folder / "scene_0002.mcap"
    original = target.read_bytes()
    try:
        target.write_bytes(original[:100] + bytes([original[100] ^ 0xFF]) + original[101:])
        result = _run("verify", str(folder))
        assert result.returncode == 1
        assert re.search(r"scene_0002\.mcap: sha256 expected [0-9a-f]{64}, actual [0-9a-f]{64}", result.stderr)
    finally:
        target.write_bytes(original)


def test_merge_names_missing_scenes(tmp_path):
    result = _run("merge", *OVERRIDES, f"root={tmp_path}")
    assert result.returncode == 2
    assert "3 of 3 scenes are not generated yet (indices [0, 1, 2])" in result.stderr


@pytest.mark.parametrize("args, message", [
    (("show", "nope"), "no dataset 'nope'"),
    (("generate",), "say which dataset spec to use: dataset=NAME"),
    (("generate", "+dataset=nope"), "nope"),
    (("generate", "+dataset=quickstart", "workers=0"), "workers must be >= 1"),
    (("verify",), "say which dataset"),
    (("generate", "+dataset=quickstart", "dataset.heldout_scenes=1"),
     "'heldout_scenes' is retired; use val_scenes and test_scenes"),
])
def test_bad_input_exits_2(tmp_path, args, message):
    result = _run(*args, f"root={tmp_path}")
    assert result.returncode == 2, result.stderr
    assert message in result.stderr
