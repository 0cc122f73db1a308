"""Fast checks of the lock file and of push/pull's refusals, on small datasets of plain files finalized here
(real folders and a real `file://` remote; the end-to-end runs are in test_data_remote.py)."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest

from samp.data.registry import DatasetError, finalize_dataset, resolve_ref


def _dataset(root: Path, name: str, content: bytes) -> Path:
    work = root / name / f".tmp-{content.hex()}"
    work.mkdir(parents=True)
    (work / "data.bin").write_bytes(content)
    return finalize_dataset(work, name, {}, root=root)


def _lock(path: Path, datasets: dict) -> Path:
    path.write_text(json.dumps({"format_version": 1, "overrides": [], "datasets": datasets, "robot_sdf": {}}))
    return path


def test_a_lock_pins_a_bare_name_and_only_a_bare_name(tmp_path, monkeypatch):
    root = tmp_path / "datasets"
    older, newer = _dataset(root, "toy", b"a"), _dataset(root, "toy", b"b")
    monkeypatch.chdir(tmp_path)
    assert resolve_ref("toy", root) == newer, "without a lock, the newest"
    _lock(tmp_path / "samp.lock", {"toy": f"toy@{older.name}"})
    assert resolve_ref("toy", root) == older, "./samp.lock pins it"
    assert resolve_ref(f"toy@{newer.name}", root) == newer, "an explicit id is not overridden"
    assert resolve_ref("toy", root, lock=False) == newer
    monkeypatch.setenv("SAMP_LOCK", "none")
    assert resolve_ref("toy", root) == newer
    monkeypatch.setenv("SAMP_LOCK", str(tmp_path / "elsewhere.lock"))
    with pytest.raises(FileNotFoundError, match="SAMP_LOCK=.*elsewhere.lock names no file"):
        resolve_ref("toy", root)
    _lock(tmp_path / "elsewhere.lock", {"toy": "toy@0123456789ab"})
    with pytest.raises(DatasetError, match=r"pinned to toy@0123456789ab by the lock file .*elsewhere\.lock.*"
                                           r"python -m samp\.data pull dataset=toy@0123456789ab remote=URL"):
        resolve_ref("toy", root)
    (tmp_path / "elsewhere.lock").write_text("{not json")
    with pytest.raises(ValueError, match="elsewhere.lock is not valid JSON"):
        resolve_ref("toy", root)


def test_pull_refusals_are_one_line_errors(tmp_path, capsys):
    from samp.data.__main__ import main

    root, remote = tmp_path / "datasets", (tmp_path / "remote").as_uri()
    folder = _dataset(root, "toy", b"a")
    assert main(["push", "toy", f"root={root}"]) == 2
    assert "say where to push: remote=URL" in capsys.readouterr().err
    assert main(["push", "toy", f"remote={remote}", f"root={root}"]) == 0
    assert main(["pull", "dataset=toy", f"remote={remote}", f"root={root}"]) == 2
    assert "say what to pull: dataset=NAME@ID remote=URL" in capsys.readouterr().err
    assert main(["pull", "dataset=toy@ffff", f"remote={remote}", f"root={tmp_path / 'other'}"]) == 2
    assert f"no dataset toy@ffff on {remote}; its toy datasets: toy@{folder.name}" in capsys.readouterr().err
    assert main(["pull", "dataset=nowhere://x/datasets/toy@ab", f"root={root}"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: remote nowhere://x: ") and "give an fsspec URL" in err, err
    assert main(["pull", "dataset=file:///x/toy@ab"]) == 2
    assert "is not a remote dataset reference: give <remote>/datasets/NAME@ID" in capsys.readouterr().err


def test_a_pull_is_kept_whole_or_not_at_all(tmp_path):
    """A file of the staging folder that the index does not name (a `.part` of a killed download) is removed;
    a dataset whose remote manifest lists a file the index lacks is refused with nothing published."""
    from samp.data.sharing import pull_dataset, push_dataset

    root, remote = tmp_path / "datasets", (tmp_path / "remote").as_uri()
    folder = _dataset(root, "toy", b"payload")
    push_dataset("toy", remote, root)
    fresh = tmp_path / "fresh"
    stray = fresh / "toy" / f".pull-{folder.name}" / "data.bin.part"
    stray.parent.mkdir(parents=True)
    stray.write_bytes(b"half")
    pulled, got, kept = pull_dataset(f"toy@{folder.name}", remote, fresh)
    assert (got, kept) == (3, 0) and sorted(p.name for p in pulled.iterdir()) == ["CARD.md", "data.bin", "manifest.json"]
    assert (pulled / "data.bin").read_bytes() == b"payload" and not stray.parent.exists()
    index_path = tmp_path / "remote" / "datasets" / f"toy@{folder.name}" / "index.json"
    index = json.loads(index_path.read_text())
    del index["files"]["data.bin"]
    from samp.remote import _index_hash

    index["index_sha256"] = _index_hash(index)  # a consistent index that leaves a file out
    index_path.write_text(json.dumps(index))
    with pytest.raises(ValueError, match=r"data\.bin: not in .*index.*nothing was published locally"):
        pull_dataset(f"toy@{folder.name}", remote, tmp_path / "third")
    assert [p.name for p in (tmp_path / "third" / "toy").iterdir()] == [f".pull-{folder.name}"]


def test_a_sweep_hands_its_lock_to_its_members(tmp_path, monkeypatch):
    """A sweep runs its members from the repository root: the lock of the folder it started in goes with them
    as $SAMP_LOCK (an absolute path), and a member resolves a bare name through it from anywhere."""
    from samp.train.sweep import keep_lock

    root = tmp_path / "datasets"
    older, _ = _dataset(root, "toy", b"a"), _dataset(root, "toy", b"b")
    _lock(tmp_path / "samp.lock", {"toy": f"toy@{older.name}"})
    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("SAMP_LOCK", "")  # recorded, so that the variable keep_lock sets is undone after the test
    monkeypatch.delenv("SAMP_LOCK")
    keep_lock()
    assert Path(os.environ["SAMP_LOCK"]) == (tmp_path / "samp.lock").resolve()
    monkeypatch.chdir(root)
    assert resolve_ref("toy", root) == older


@pytest.mark.slow  # composes the training config (seconds)
def test_lock_flag_writes_the_newest_ids_and_keeps_other_names(tmp_path, monkeypatch, capsys):
    from samp.train.cli import main

    root = tmp_path / "datasets"
    _dataset(root, "toy", b"a")
    newer = _dataset(root, "toy", b"b")
    lock = _lock(tmp_path / "team.lock", {"other": "other@0123456789ab"})
    monkeypatch.chdir(tmp_path)
    args = ["experiment=mpnet", "datamodule.dataset=toy", f"datamodule.root={root}", "evaluation.benchmark=null"]
    assert main([*args, f"--lock={lock}"]) == 0
    assert f"toy -> toy@{newer.name}" in capsys.readouterr().out
    written = json.loads(lock.read_text())
    assert written["datasets"] == {"other": "other@0123456789ab", "toy": f"toy@{newer.name}"}
    assert written["overrides"] == args and not (tmp_path / "samp.lock").exists()
    assert main([*args, "-m", "--lock"]) == 2
    assert "--lock pins the inputs of one config" in capsys.readouterr().err
