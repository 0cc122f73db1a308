"""Dataset faults replayed: a damaged work file is re-planned, never merged; stale temporaries go before
anything new is written; two generations of one name; a full disk, a read-only folder, a name too long and a
folder variable that is a file each give one line (exit 2) and leave no partial output; `ls` marks damaged
datasets; hints to paste are shell-quoted; typos in generation keys are named; the card says the scene-file
format.

A full disk is replayed with a file-size limit (RLIMIT_FSIZE, SIGXFSZ ignored): the write fails with EFBIG
where a full disk gives ENOSPC, through the same code path. A read-only folder is a read-only bind mount in
a mount namespace of its own where the test runs as root (`unshare -m`), else a folder without write
permission."""

from __future__ import annotations

import json
import os
import resource
import shlex
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from samp.data import GenerationError, generate, merge, read_manifest, verify_dataset
from samp.data.generation import work_dir
from samp.data.registry import manifest_hash
from samp.data.spec import load_spec

pytestmark = pytest.mark.slow  # dataset generation: deselected by `make test-fast`

SPEC = {"name": "faulty", "robot": "panda", "seed": 3, "train_scenes": 2, "val_scenes": 0, "test_scenes": 0,
        "trajectories_per_scene": 2, "eval_problems_per_scene": 0, "generators": ["tabletop"], "resolutions": [8],
        "detour_share": 0.0}
OVERRIDES = ["dataset=quickstart", "dataset.name=faulty", "dataset.seed=3", "dataset.train_scenes=2",
             "dataset.val_scenes=0", "dataset.test_scenes=0", "dataset.trajectories_per_scene=2",
             "dataset.eval_problems_per_scene=0", "dataset.generators=[tabletop]", "dataset.resolutions=[8]",
             "dataset.detour_share=0", "progress=false"]  # SPEC's
DEADLINE = 180  # seconds: only a bound on a poll, never a timing that is asserted


def _cli(*args: str, env: dict | None = None, preexec=None, prefix: tuple[str, ...] = ()):
    env = {**os.environ, "OMP_NUM_THREADS": "1", **(env or {})}
    return subprocess.run([*prefix, sys.executable, "-m", "samp.data", *args], capture_output=True, text=True,
                          timeout=600, env=env, preexec_fn=preexec)


def _one_error_line(proc) -> str:
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 2 and len(lines) == 1 and lines[0].startswith("error: "), proc.stderr[-3000:]
    assert "Traceback" not in proc.stderr
    return lines[0]


@pytest.fixture(scope="module")
def made(tmp_path_factory):
    """(dataset folder, datasets root) of SPEC."""
    root = tmp_path_factory.mktemp("datasets")
    return generate(SPEC, root=root, progress=False), root


def _copy(made, root: Path, name: str | None = None) -> Path:
    """A copy of the dataset under `root`, renamed `name` (its manifest re-hashed, so only what the test breaks
    is wrong)."""
    folder = made[0]
    name = name or folder.parent.name
    dest = root / name / folder.name
    shutil.copytree(folder, dest)
    if name != folder.parent.name:
        manifest = json.loads((dest / "manifest.json").read_text())
        manifest["name"] = name
        manifest["manifest_sha256"] = manifest_hash(manifest)
        (dest / "manifest.json").write_text(json.dumps(manifest, indent=2, sort_keys=True))
    return dest


# ------------------------------------------------------------------------------------- verify before publishing
def test_a_truncated_work_file_is_replanned_never_merged(made, tmp_path, capsys):
    """The fault: generation killed, one file in `.work/` truncated, the same command again -> "resuming", a
    new dataset id published with the unreadable scene file in it."""
    root = tmp_path / "datasets"
    spec = load_spec(SPEC)
    assert generate(SPEC, shard=0, num_shards=2, root=root, progress=False) is None  # scene 0 only
    work = work_dir(spec, root)
    scene, sidecar = work / "scene_0000.mcap", work / "scene_0000.mcap.json"
    intact, record = scene.read_bytes(), sidecar.read_text()
    scene.write_bytes(intact[: len(intact) // 2])  # the machine died while the file was written out
    with pytest.raises(GenerationError, match=r"2 of 2 scenes are not generated yet \(indices \[0, 1\]\)"):
        merge(SPEC, root)
    out = capsys.readouterr().out
    assert f"{scene} is damaged ({scene} is not a readable samp scene file" in out, out
    assert "removing it: scene 0 is planned again" in out and not scene.exists() and not sidecar.exists()
    scene.write_bytes(intact[: len(intact) // 2])  # damaged again, now for the resume
    sidecar.write_text(record)
    dest = generate(SPEC, root=root, progress=False)
    out = capsys.readouterr().out
    assert f"{scene} is damaged (" in out and "resuming" not in out, out
    assert verify_dataset(dest) == []
    # the re-planned scene is the one a clean generation makes: the same spec and seed give the same bytes
    assert read_manifest(dest)["id"] == read_manifest(made[0])["id"]


def test_stale_temporaries_are_cleared_before_anything_is_written(tmp_path):
    from samp.data.workfolder import TMP_STALE_S, clear_stale

    files = ["scene_0000.mcap", "scene_0001.mcap"]
    stale = [tmp_path / "scene_0000.mcap.tmp", tmp_path / "scene_0001.mcap.json.tmp", tmp_path / "spec.json.7-1.tmp"]
    others = [tmp_path / "scene_0002.mcap.tmp", tmp_path / "spec.json.8-2.tmp"]  # another shard's, a live writer's
    for f in stale + others:
        f.write_text("x")
    old = time.time() - 2 * TMP_STALE_S
    os.utime(stale[2], (old, old))
    assert clear_stale(tmp_path, files) == 3
    assert not any(f.exists() for f in stale) and all(f.exists() for f in others)


def _fsize_limit(limit: int):
    def preexec():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # EFBIG instead of a signal, as ENOSPC comes as an error
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return preexec


def test_a_full_disk_gives_one_line_and_no_partial_file_and_the_rerun_finishes(made, tmp_path):
    """The fault: a traceback, and the re-run failed again because spec.json was written before the stale
    temporaries were removed."""
    root = tmp_path / "datasets"
    spec = load_spec(SPEC)
    work = work_dir(spec, root)
    work.mkdir(parents=True)
    (work / "scene_0001.mcap.tmp").write_bytes(b"\0" * 4096)  # left by a run killed while writing
    limit = (made[0] / "scene_0000.mcap").stat().st_size // 2  # spec.json and sidecars fit, no scene file does
    proc = _cli("generate", *OVERRIDES, f"root={root}", preexec=_fsize_limit(limit))
    line = _one_error_line(proc)
    assert line.startswith("error: a file grew past the size this system allows (ulimit -f) at ") and \
        str(work / "scene_0000.mcap.tmp") in line, line
    assert [p.name for p in work.iterdir()] == ["spec.json"], list(work.iterdir())  # no partial output, no stale
    proc = _cli("generate", *OVERRIDES, f"root={root}")
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert verify_dataset(next((root / "faulty").glob("[0-9a-f]*"))) == []


# ------------------------------------------------------------------------------------- two generations at once
HOLD = """
import time
import samp.data.generation as generation

_run_scene = generation.run_scene


def run_scene(*args, **kwargs):
    time.sleep(120)  # held until the test has tried a second generation and killed this one
    return _run_scene(*args, **kwargs)


generation.run_scene = run_scene
"""


def test_a_second_generation_of_one_name_exits_naming_the_first(tmp_path, capsys):
    """The fault: the loser exited with a raw `[Errno 2] ... scene_0001.mcap.json.tmp`."""
    from samp.data.workfolder import generation_lock

    root, site = tmp_path / "datasets", tmp_path / "site"
    site.mkdir()
    (site / "sitecustomize.py").write_text(HOLD)
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": os.pathsep.join([str(site), *sys.path])}
    first = subprocess.Popen([sys.executable, "-m", "samp.data", "generate", *OVERRIDES, f"root={root}"], env=env,
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        work = work_dir(load_spec(SPEC), root)
        deadline = time.monotonic() + DEADLINE
        while not (work / "generate-all.lock").exists():
            assert first.poll() is None and time.monotonic() < deadline, "the first generation never took its lock"
            time.sleep(0.05)
        line = _one_error_line(_cli("generate", *OVERRIDES, f"root={root}"))
        assert f"faulty: process {first.pid} on " in line and f"is already generating all scenes into {work}" in line
        line = _one_error_line(_cli("generate", *OVERRIDES, f"root={root}", "shard=1", "num_shards=2"))
        assert f"process {first.pid} on " in line, line  # a shard covers scenes of the whole
    finally:
        first.send_signal(signal.SIGKILL)
        first.wait()
    with generation_lock(work, "faulty"):  # its holder is gone: the lock is taken over with a warning
        pass
    assert f"taking over the generation lock {work / 'generate-all.lock'} of process {first.pid}" in \
        capsys.readouterr().err


# ------------------------------------------------------------------------------------- environment faults
def test_a_read_only_folder_gives_one_line(tmp_path):
    ro = tmp_path / "ro"
    ro.mkdir()
    if os.geteuid() == 0:  # root writes through permissions: a read-only bind mount in a namespace of its own
        if shutil.which("unshare") is None or subprocess.run(["unshare", "-m", "true"]).returncode != 0:
            pytest.skip("running as root without mount namespaces: no way to make a folder read-only")
        mount = f"mount --bind {shlex.quote(str(ro))} {shlex.quote(str(ro))} && " \
                f"mount -o remount,ro,bind {shlex.quote(str(ro))} && exec \"$@\""
        prefix = ("unshare", "-m", "sh", "-c", mount, "sh")
        expected = "error: the file system is read-only at "
    else:
        ro.chmod(0o555)
        prefix, expected = (), "error: permission denied for "
    line = _one_error_line(_cli("generate", *OVERRIDES, f"root={ro}", prefix=prefix))
    assert line.startswith(expected) and str(ro / "faulty") in line, line
    assert list(ro.iterdir()) == []


def test_a_name_too_long_gives_one_line(tmp_path):
    name = "n" * 300
    line = _one_error_line(_cli("generate", *OVERRIDES, f"dataset.name={name}", f"root={tmp_path}"))
    assert line.startswith(f"error: a name is too long for the file system in {tmp_path / name}"), line
    assert "choose a shorter name" in line and list(tmp_path.iterdir()) == []


def test_a_datasets_variable_that_is_a_file_gives_one_line(tmp_path):
    (tmp_path / "file").write_text("x")
    line = _one_error_line(_cli("ls", env={"SAMP_DATASETS_DIR": str(tmp_path / "file")}))
    assert line == f"error: SAMP_DATASETS_DIR={tmp_path / 'file'} is a file, not a folder; point SAMP_DATASETS_DIR " \
                   "at a folder (it is created when missing)", line


def test_generation_key_typos_name_the_valid_keys(capsys):
    from samp.data.__main__ import main

    assert main(["generate", "dataset=smoke", "workrs=2"]) == 2
    assert capsys.readouterr().err.strip() == (
        "error: unknown key 'workrs' (did you mean 'workers'?); settings: workers, shard, num_shards, root, progress, "
        "dataset=NAME, dataset.KEY=VALUE")
    assert main(["generate", "dataset=smoke", "dataset.train_scene=2"]) == 2
    assert "unknown key 'dataset.train_scene' (did you mean 'dataset.train_scenes'?)" in capsys.readouterr().err


# ------------------------------------------------------------------------------------- ls, hints, card
def test_ls_marks_truncated_and_missing_files_damaged(made, tmp_path, capsys):
    from samp.data.__main__ import main

    cut, gone = _copy(made, tmp_path / "a"), _copy(made, tmp_path / "b")
    (cut / "scene_0001.mcap").write_bytes((cut / "scene_0001.mcap").read_bytes()[:100])
    (gone / "scene_0000.mcap").unlink()
    for folder, what in ((cut, "has 100 bytes, the manifest says"), (gone, "file scene_0000.mcap is missing")):
        assert main(["ls", f"root={folder.parent.parent}"]) == 0
        out = capsys.readouterr().out
        assert f"faulty@{folder.name} DAMAGED: dataset {folder}" in " ".join(out.split()) and what in out, out
    assert main(["ls", f"root={made[1]}"]) == 0
    assert "DAMAGED" not in capsys.readouterr().out


def test_the_repair_hint_is_shell_quoted(made, tmp_path, capsys):
    """The fault: a manifest named `a;rm -rf x` with a file missing printed an unquoted command to paste."""
    from samp.data.__main__ import main

    folder = _copy(made, tmp_path, name="a;rm -rf x")
    (folder / "scene_0000.mcap").unlink()
    assert main(["inspect", str(folder)]) == 2
    err = capsys.readouterr().err
    hint = err.split("generate it again with `")[1].split("`")[0]
    assert hint == "python -m samp.data generate 'dataset=a;rm -rf x'", err
    assert shlex.split(hint) == ["python", "-m", "samp.data", "generate", "dataset=a;rm -rf x"]


def test_the_card_says_the_scene_file_format(made):
    from samp.data.registry import SCENE_FILE_VERSION

    card = (made[0] / "CARD.md").read_text()
    assert f"scene files of format {SCENE_FILE_VERSION}, manifest format 2" in card
    assert read_manifest(made[0])["scene_file_version"] == SCENE_FILE_VERSION == 3


def test_a_manifest_larger_than_the_limit_is_refused_before_it_is_read(tmp_path, monkeypatch):
    import samp.data.registry as registry
    from samp.data import DatasetError

    folder = tmp_path / "big" / "0123456789ab"
    folder.mkdir(parents=True)
    (folder / "manifest.json").write_text(json.dumps({"format_version": 2, "pad": "x" * 100}))
    monkeypatch.setattr(registry, "MAX_MANIFEST_BYTES", 64)
    with pytest.raises(DatasetError, match=r"manifest.json has \d+ bytes, more than the 64 a manifest may have"):
        read_manifest(folder)
