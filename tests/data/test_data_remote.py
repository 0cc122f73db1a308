"""Datasets and runs shared through remotes, against real ones: a `file://` folder and an S3 API server
(moto's server mode) started here. push -> delete local -> pull -> train gives the same dataset id, byte
for byte; a damaged remote file is refused, naming it, with nothing published; an interrupted push or
pull continues where it stopped; a run goes the same way; a lock file pins a bare name although a newer
dataset of that name exists."""

from __future__ import annotations

import contextlib
import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
from pathlib import Path

import pytest

from samp.paths import file_sha256

pytestmark = pytest.mark.slow  # dataset generation, training and a server: deselected by `make test-fast`

BUCKET = "samp-test"
# The fewest steps that train and evaluate a policy: the small MPNet of the baseline tests on the smoke data.
TRAIN = ["+experiment=mpnet", "datamodule.n_e=16", "trainer.max_steps=4", "trainer.max_epochs=-1",
         "trainer.log_every_n_steps=1", "trainer.enable_progress_bar=false", "datamodule.batch_size=8",
         "datamodule.val_samples=8", "evaluation.problems=1", "evaluation.benchmark=null", "model.channels=[4,8]",
         "model.code=16", "model.hidden=[32,16]", "system.planning.time_limit=2.0"]


def _env(**extra) -> dict:
    return {**os.environ, "RERUN_ANALYTICS": "0", "OMP_NUM_THREADS": "1", **extra}


def _cli(module: str, *args: str, cwd: Path | None = None, prelude: str | None = None, popen: bool = False, **env):
    cmd = [sys.executable, "-m", module, *args]
    if prelude is not None:  # Python run in that process first, then the module as `python -m` runs it
        cmd = [sys.executable, "-c", f"{prelude}\nimport runpy, sys\nsys.argv = [{module!r}, *sys.argv[1:]]\n"
               f"runpy.run_module({module!r}, run_name='__main__', alter_sys=True)\n", *args]
    if popen:
        return subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, env=_env(**env), cwd=cwd)
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600, env=_env(**env), cwd=cwd)


def _data(*args: str) -> subprocess.CompletedProcess:
    """`python -m samp.data ARGS` in this process (its `main`, output captured): the same code as the command
    line without a new interpreter's start, for the many short pushes and pulls."""
    from samp.data.__main__ import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return subprocess.CompletedProcess(["samp.data", *args], code, out.getvalue(), err.getvalue())


def _ok(proc: subprocess.CompletedProcess) -> str:
    assert proc.returncode == 0, f"{proc.args[1:4]} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    return proc.stdout


def _hashes(folder: Path) -> dict[str, str]:
    """{path: sha256} of every file in a folder: the oracle of "byte-identical"."""
    return {p.relative_to(folder).as_posix(): file_sha256(p) for p in sorted(folder.rglob("*")) if p.is_file()}


def _published(root: Path, name: str) -> list[str]:
    return sorted(p.name for p in (root / name).iterdir() if not p.name.startswith(".")) if (root / name).is_dir() else []


@pytest.fixture(scope="module")
def smoke(tmp_path_factory) -> tuple[Path, str, dict[str, str]]:
    """(a datasets folder with the smoke dataset, its id, the sha256 of every file in it)."""
    root = tmp_path_factory.mktemp("origin")
    _ok(_cli("samp.data", "generate", "dataset=smoke", f"root={root}", "progress=false"))
    (folder,) = [p for p in (root / "smoke").iterdir() if not p.name.startswith(".")]
    return root, folder.name, _hashes(folder)


@pytest.fixture(scope="module")
def s3(tmp_path_factory):
    """An S3 API server (moto in server mode) on a free local port with one bucket; the AWS variables
    point this process and its children at it, as a user points samp at their own S3 endpoint."""
    from moto.server import ThreadedMotoServer

    server = ThreadedMotoServer(ip_address="127.0.0.1", port=0, verbose=False)
    server.start()
    host, port = server.get_host_and_port()
    mp = pytest.MonkeyPatch()
    for key, value in {"AWS_ENDPOINT_URL": f"http://{host}:{port}", "AWS_ACCESS_KEY_ID": "test",
                       "AWS_SECRET_ACCESS_KEY": "test", "AWS_DEFAULT_REGION": "us-east-1"}.items():
        mp.setenv(key, value)
    import fsspec

    fsspec.filesystem("s3", skip_instance_cache=True).mkdir(BUCKET)
    yield f"s3://{BUCKET}"
    mp.undo()
    server.stop()


@pytest.fixture(params=["file", "s3"])
def remote(request, tmp_path):
    """A fresh remote of each kind: a folder, or a prefix of the S3 server's bucket."""
    if request.param == "file":
        return (tmp_path / "remote").as_uri()
    return f"{request.getfixturevalue('s3')}/{tmp_path.name}"


def _copy(smoke, tmp: Path) -> Path:
    """A datasets folder of the test's own holding the smoke dataset."""
    root = tmp / "local"
    shutil.copytree(smoke[0], root)
    return root


def _blob(remote: str, sha256: str) -> str:
    from samp.remote import blob_url

    return blob_url(remote, sha256)


def test_push_delete_pull_gives_the_same_bytes_and_id(smoke, remote, tmp_path):
    _, ident, hashes = smoke
    root = _copy(smoke, tmp_path)
    out = _ok(_data("push", f"dataset=smoke@{ident}", f"remote={remote}", f"root={root}"))
    assert f"pushed {remote}/datasets/smoke@{ident}: {len(hashes)} files uploaded, 0 already there" in out, out
    again = _ok(_data("push", "smoke", f"remote={remote}", f"root={root}"))
    assert f"0 files uploaded, {len(hashes)} already there" in again, again
    shutil.rmtree(root / "smoke")
    out = _ok(_data("pull", f"dataset=smoke@{ident[:6]}", f"remote={remote}", f"root={root}"))
    assert f"pulled smoke@{ident} into {root / 'smoke' / ident}: {len(hashes)} files downloaded" in out, out
    assert _hashes(root / "smoke" / ident) == hashes
    assert sorted(p.name for p in (root / "smoke").iterdir()) == [ident], "no staging folder is left behind"
    _ok(_data("verify", f"smoke@{ident}", f"root={root}"))


def test_damaged_remote_file_is_refused_naming_it(smoke, remote, tmp_path):
    import fsspec

    _, ident, hashes = smoke
    root = _copy(smoke, tmp_path)
    _ok(_data("push", f"smoke@{ident}", f"remote={remote}", f"root={root}"))
    shutil.rmtree(root / "smoke")
    fs, blob = fsspec.core.url_to_fs(_blob(remote, hashes["scene_0001.mcap"]))
    data = bytearray(fs.cat_file(blob))
    data[len(data) // 2] ^= 0xFF
    fs.pipe_file(blob, bytes(data))
    proc = _data("pull", f"dataset={remote}/datasets/smoke@{ident}", f"root={root}")
    assert proc.returncode == 2, proc.stdout + proc.stderr
    assert re.search(rf"remote file scene_0001\.mcap of {re.escape(remote)}/datasets/smoke@{ident} is damaged: sha256 "
                     rf"expected {hashes['scene_0001.mcap']}, actual [0-9a-f]{{64}}", proc.stderr), proc.stderr
    assert "nothing was published locally" in proc.stderr and "Push it again from an intact copy" in proc.stderr
    assert _published(root, "smoke") == [], "a damaged pull publishes nothing"
    again = _ok(_data("push", f"smoke@{ident}", f"remote={remote}", f"root={smoke[0]}"))
    assert f"1 file uploaded, {len(hashes) - 1} already there" in again, "a damaged blob of the right size was kept"
    forced = _ok(_data("push", f"smoke@{ident}", f"remote={remote}", "force=true", f"root={smoke[0]}"))
    assert f"{len(hashes)} files uploaded, 0 already there" in forced, forced
    _ok(_data("pull", f"smoke@{ident}", f"remote={remote}", f"root={root}"))
    assert _hashes(root / "smoke" / ident) == hashes, "the pull that failed continues, now from intact blobs"
    shutil.rmtree(root / "smoke")
    index = f"{remote}/datasets/smoke@{ident}/index.json"  # an edited index is refused too
    fs, path = fsspec.core.url_to_fs(index)
    edited = json.loads(fs.cat_file(path))
    edited["files"]["scene_0001.mcap"]["sha256"] = file_sha256(Path(__file__))
    fs.pipe_file(path, json.dumps(edited).encode())
    proc = _data("pull", f"smoke@{ident}", f"remote={remote}", f"root={root}")
    assert proc.returncode == 2 and f"{index} was changed after it was pushed" in proc.stderr, proc.stderr


# Run in the push or pull process (`_cli(..., prelude=STOP_AFTER_FIRST.format(METHOD))`): fsspec's local file
# system stops the process (SIGSTOP) when it is asked for its second transfer, so the first file is done
# (uploaded; or downloaded, checked and named) and the test kills the process at that point.
STOP_AFTER_FIRST = """
import os, signal
from fsspec.implementations.local import LocalFileSystem

_method, _calls = getattr(LocalFileSystem, {0!r}), []

def _stop_at_second(self, *args, **kwargs):
    _calls.append(args)
    if len(_calls) == 2:
        os.kill(os.getpid(), signal.SIGSTOP)
    return _method(self, *args, **kwargs)

setattr(LocalFileSystem, {0!r}, _stop_at_second)
"""


def _killed_after_first_file(method: str, *args: str) -> None:
    proc = _cli("samp.data", *args, prelude=STOP_AFTER_FIRST.format(method), popen=True)
    _, status = os.waitpid(proc.pid, os.WUNTRACED)
    assert os.WIFSTOPPED(status), f"{args[0]} ended (status {status}) instead of stopping after its first file"
    proc.send_signal(signal.SIGKILL)
    proc.wait()


def test_interrupted_push_and_pull_continue(smoke, tmp_path):
    _, ident, hashes = smoke
    root, remote = _copy(smoke, tmp_path), (tmp_path / "remote").as_uri()
    _killed_after_first_file("put_file", "push", f"smoke@{ident}", f"remote={remote}", f"root={root}")
    assert not (tmp_path / "remote" / "datasets").exists(), "the index is written last, after every file"
    out = _ok(_cli("samp.data", "push", f"smoke@{ident}", f"remote={remote}", f"root={root}"))
    assert f"{len(hashes) - 1} files uploaded, 1 already there" in out, out
    shutil.rmtree(root / "smoke")
    _killed_after_first_file("get_file", "pull", f"smoke@{ident}", f"remote={remote}", f"root={root}")
    assert _published(root, "smoke") == [], "an interrupted pull publishes nothing"
    staged = {p.name: p.stat().st_ino for p in (root / "smoke" / f".pull-{ident}").rglob("*") if p.is_file()}
    assert len(staged) == 1, staged
    out = _ok(_cli("samp.data", "pull", f"smoke@{ident}", f"remote={remote}", f"root={root}"))
    assert f"{len(hashes) - 1} files downloaded, 1 kept (intact)" in out, out
    assert _hashes(root / "smoke" / ident) == hashes
    (kept,) = staged.items()  # the file the killed pull verified is the one published
    assert (root / "smoke" / ident / kept[0]).stat().st_ino == kept[1]


@pytest.fixture(scope="module")
def trained(smoke, s3, tmp_path_factory):
    """push to the S3 server -> delete local -> train with `datamodule.dataset=<remote>/datasets/smoke@ID`
    into an empty datasets folder: (the run folder, the folder the training pulled, the remote)."""
    tmp = tmp_path_factory.mktemp("trained")
    root = _copy(smoke, tmp)
    remote = f"{s3}/team"
    _ok(_cli("samp.data", "push", f"smoke@{smoke[1]}", f"remote={remote}", f"root={root}"))
    shutil.rmtree(root)
    runs, fresh = tmp / "runs", tmp / "datasets"
    _ok(_cli("samp.train", *TRAIN, f"datamodule.dataset={remote}/datasets/smoke@{smoke[1]}",
             SAMP_RUNS_DIR=str(runs), SAMP_DATASETS_DIR=str(fresh)))
    (run,) = (runs / "mpnet").iterdir()
    return run, fresh / "smoke" / smoke[1], remote


def test_training_on_a_remote_reference_pulls_the_same_dataset(smoke, trained):
    run, pulled, _ = trained
    record = json.loads((run / "run.json").read_text())
    assert record["status"] == "completed" and record["dataset_id"] == f"smoke@{smoke[1]}"
    assert _hashes(pulled) == smoke[2]


def test_run_push_delete_pull_round_trip(trained, tmp_path):
    run, _, remote = trained
    record = json.loads((run / "run.json").read_text())
    assert "checkpoints/last.ckpt" in record["files_sha256"]
    before = _hashes(run)
    for where in (remote, (tmp_path / "remote").as_uri()):
        out = _ok(_cli("samp.runs", "push", str(run), f"remote={where}"))
        assert f"pushed {where}/runs/mpnet/{run.name}: {len(before)} files uploaded" in out, out
        runs = tmp_path / where.partition(":")[0]
        if where.startswith("s3:"):  # the run's URL, or EXPERIMENT/RUN with the remote: the same
            out = _ok(_cli("samp.runs", "pull", f"run={where}/runs/mpnet/{run.name}", f"root={runs}"))
        else:
            out = _ok(_cli("samp.runs", "pull", f"mpnet/{run.name}", f"remote={where}", f"root={runs}"))
        assert f"pulled into {runs / 'mpnet' / run.name}: {len(before)} files downloaded" in out, out
        assert _hashes(runs / "mpnet" / run.name) == before
        shown = _ok(_cli("samp.runs", "show", str(runs / "mpnet" / run.name)))
        assert "smoke@" in shown and "completed" in shown


def test_lock_pins_a_bare_name_when_a_newer_dataset_exists(smoke, tmp_path):
    _, ident, _ = smoke
    root, remote = _copy(smoke, tmp_path), (tmp_path / "remote").as_uri()
    env = {"SAMP_DATASETS_DIR": str(root), "SAMP_RUNS_DIR": str(tmp_path / "runs")}
    out = _ok(_cli("samp.train", *TRAIN, "datamodule.dataset=smoke", "--lock", cwd=tmp_path, **env))
    assert f"smoke -> smoke@{ident}" in out, out
    assert json.loads((tmp_path / "samp.lock").read_text())["datasets"] == {"smoke": f"smoke@{ident}"}
    _ok(_cli("samp.data", "generate", "dataset=smoke", "dataset.seed=1", f"root={root}", "progress=false"))
    newer = [p for p in _published(root, "smoke") if p != ident]
    assert len(newer) == 1, "a second smoke dataset, the newest of that name"
    assert f'"id": "{newer[0]}"' in _ok(_cli("samp.data", "show", "smoke", cwd=root, **env)), \
        "without the lock (none in that folder), the bare name floats to the newest"
    assert f'"id": "{ident}"' in _ok(_cli("samp.data", "show", "smoke", cwd=tmp_path, **env))
    _ok(_cli("samp.data", "push", f"smoke@{ident}", f"remote={remote}", cwd=tmp_path, **env))
    shutil.rmtree(root / "smoke" / ident)
    proc = _cli("samp.train", *TRAIN, "datamodule.dataset=smoke", cwd=tmp_path, **env)
    assert proc.returncode != 0
    assert f"pinned to smoke@{ident} by the lock file {tmp_path / 'samp.lock'}" in proc.stderr, proc.stderr[-2000:]
    assert f"python -m samp.data pull dataset=smoke@{ident} remote=URL" in proc.stderr
    _ok(_cli("samp.data", "pull", f"dataset=smoke@{ident}", f"remote={remote}", cwd=tmp_path, **env))
    _ok(_cli("samp.train", *TRAIN, "datamodule.dataset=smoke", cwd=tmp_path, **env))
    (run,) = (tmp_path / "runs" / "mpnet").iterdir()
    record = json.loads((run / "run.json").read_text())
    assert record["dataset_id"] == f"smoke@{ident}", "the pinned dataset, not the newest"
    assert record["lock"]["path"] == str((tmp_path / "samp.lock").resolve())
    assert record["lock"]["datasets"] == {"smoke": f"smoke@{ident}"}
