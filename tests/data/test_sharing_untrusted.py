""""Here already" is said only of an intact copy (issue 52): a push replaces a remote blob of the right size
whose bytes differ; a pull over a damaged local dataset re-downloads the damaged files, each checked by its
sha256, and keeps the damaged copy aside; a generate over a damaged dataset of its spec refuses in one line
naming the file and what to do. Real files and a `file://` remote; the datasets are small stand-ins made by
`finalize_dataset` (a manifest and two data files), which is all that verification and sharing read."""

from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import pytest

from samp.data.registry import MANIFEST, finalize_dataset, verify_dataset
from samp.paths import file_sha256
from samp.remote import blob_url, push_folder


def _flip(path: Path) -> None:
    """One flipped bit in the middle of `path`: its size stays, its sha256 changes."""
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 1
    path.write_bytes(bytes(data))


def _dataset(root: Path, name: str = "mine", **manifest) -> Path:
    tmp = root / ".tmp-build"
    tmp.mkdir(parents=True)
    (tmp / "a.bin").write_bytes(bytes(range(256)) * 64)
    (tmp / "b.bin").write_bytes(b"samp" * 4096)
    return finalize_dataset(tmp, name, manifest, root)


def _main(*args: str) -> tuple[int, str, str]:
    """`python -m samp.data ARGS` in this process: (exit status, stdout, stderr)."""
    from samp.data.__main__ import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main(list(args))
    return code, out.getvalue(), err.getvalue()


def test_push_replaces_a_same_size_damaged_blob_on_the_remote(tmp_path):
    folder = tmp_path / "entry"
    folder.mkdir()
    (folder / "x.bin").write_bytes(b"0123456789" * 1000)
    files = {"x.bin": {"sha256": file_sha256(folder / "x.bin"), "size": 10000}}
    remote = (tmp_path / "remote").as_uri()
    assert push_folder(folder, files, remote, "things/x", {}) == (1, 0)
    blob = Path(blob_url(str(tmp_path / "remote"), files["x.bin"]["sha256"]))
    _flip(blob)
    assert push_folder(folder, files, remote, "things/x", {}) == (1, 0), "the damaged blob was kept"
    assert file_sha256(blob) == files["x.bin"]["sha256"], "the blob on the remote is still damaged"
    assert push_folder(folder, files, remote, "things/x", {}) == (0, 1), "an intact blob is not sent again"


def test_pull_repairs_a_damaged_local_copy_from_the_remote(tmp_path):
    root = tmp_path / "datasets"
    dest = _dataset(root)
    remote = (tmp_path / "remote").as_uri()
    assert _main("push", "dataset=mine", f"remote={remote}", f"root={root}")[0] == 0
    _flip(dest / "a.bin")
    (dest / "notes.txt").write_text("mine")  # something of the user's in the folder: never deleted
    ref = f"mine@{dest.name}"
    code, out, err = _main("pull", f"dataset={ref}", f"remote={remote}", f"root={root}")
    assert code == 0, err
    assert "here already" not in out, out
    assert verify_dataset(dest) == [], "the pulled copy is still damaged"
    assert "a.bin" in out and "1 file downloaded" in out, out
    aside = [p for p in (root / "mine").iterdir() if p.name.startswith(".damaged-")]
    assert len(aside) == 1 and (aside[0] / "notes.txt").read_text() == "mine", "the damaged copy was not kept aside"
    assert str(aside[0]) in out, out
    code, out, _ = _main("pull", f"dataset={ref}", f"remote={remote}", f"root={root}")
    assert code == 0 and "here already" in out, out


def test_pull_over_a_damaged_copy_refuses_in_one_line_when_the_remote_cannot_repair_it(tmp_path):
    root = tmp_path / "datasets"
    dest = _dataset(root)
    remote = (tmp_path / "remote").as_uri()
    _main("push", "dataset=mine", f"remote={remote}", f"root={root}")
    index = json.loads((tmp_path / "remote" / "datasets" / f"mine@{dest.name}" / "index.json").read_text())
    _flip(dest / "a.bin")
    _flip(Path(blob_url(str(tmp_path / "remote"), index["files"]["a.bin"]["sha256"])))
    code, out, err = _main("pull", f"dataset=mine@{dest.name}", f"remote={remote}", f"root={root}")
    assert code != 0 and len(err.strip().splitlines()) == 1, (out, err)
    assert "a.bin" in err and "damaged" in err, err
    assert (dest / MANIFEST).is_file() and (dest / "a.bin").is_file(), "the local copy was removed"


def test_generate_over_a_damaged_dataset_of_its_spec_refuses_in_one_line(tmp_path):
    from samp.data.spec import load_spec

    spec = load_spec("smoke")
    root = tmp_path / "datasets"
    counts = dict.fromkeys(("scenes", "train_scenes", "val_scenes", "test_scenes", "trajectories", "failures",
                            "eval_problems", "eval_failures"), 0)
    dest = _dataset(root, "smoke", config_hash=spec.config_hash(), counts=counts, planning_time={"total_s": 0.0},
                    eval_planning_time={"total_s": 0.0})
    code, out, _ = _main("generate", "dataset=smoke", f"root={root}", "progress=false")
    assert code == 0 and "nothing to plan" in out, out  # intact: found, nothing planned
    _flip(dest / "b.bin")
    code, out, err = _main("generate", "dataset=smoke", f"root={root}", "progress=false")
    assert code != 0 and "nothing to plan" not in out, (out, err)
    lines = err.strip().splitlines()
    assert len(lines) == 1 and "b.bin" in lines[0] and str(dest) in lines[0], lines
    assert "move it aside" in lines[0] or "delete" in lines[0], lines
    assert (dest / "b.bin").is_file(), "the damaged dataset was removed"


def test_a_dataset_made_again_is_not_swapped_for_a_damaged_copy_of_the_same_id(tmp_path):
    from samp.data.registry import DatasetError

    root = tmp_path / "datasets"
    first = _dataset(root)
    _flip(first / "a.bin")
    with pytest.raises(DatasetError, match=r"here already and damaged .*a\.bin.*Move the damaged one aside"):
        _dataset(root)
