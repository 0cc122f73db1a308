"""The dataset registry's checks in the fast tier, on small hand-made datasets (no generation): a changed byte
in a data file or an edited manifest entry is detected, the id is the content's, and a name means its
newest dataset."""

from __future__ import annotations

import json

import pytest

from samp.data.registry import DatasetError, finalize_dataset, read_manifest, resolve_ref, verify_dataset


def _make(root, name: str = "pins", payload: bytes = b"scene bytes " * 50, extra: dict | None = None):
    tmp = root / f".tmp-{name}-{len(list(root.glob('.tmp-*')))}"
    (tmp / "scenes").mkdir(parents=True)
    (tmp / "scenes" / "scene_0000.mcap").write_bytes(payload)
    (tmp / "grids.npy").write_bytes(b"grid bytes " * 20)
    return finalize_dataset(tmp, name, {"robot": {"name": "panda"}, **(extra or {})}, root)


def test_a_changed_byte_in_a_data_file_is_detected(tmp_path):
    folder = _make(tmp_path)
    assert verify_dataset(folder) == []
    path = folder / "scenes" / "scene_0000.mcap"
    data = bytearray(path.read_bytes())
    data[100] ^= 0x01  # one bit: the size is unchanged, only the hash can tell
    path.write_bytes(bytes(data))
    problems = verify_dataset(folder)
    assert len(problems) == 1 and problems[0].startswith("scenes/scene_0000.mcap: sha256 expected"), problems


def test_an_edited_manifest_entry_is_refused(tmp_path):
    folder = _make(tmp_path)
    manifest = json.loads((folder / "manifest.json").read_text())
    manifest["files"]["grids.npy"]["sha256"] = "0" * 64  # a file entry edited to match something else
    (folder / "manifest.json").write_text(json.dumps(manifest))
    with pytest.raises(DatasetError, match="was changed after the dataset was written"):
        read_manifest(folder)
    assert "was changed after the dataset was written" in verify_dataset(folder)[0]


def test_a_missing_and_an_unlisted_file_are_named(tmp_path):
    folder = _make(tmp_path)
    (folder / "grids.npy").rename(folder / "stray.npy")
    assert sorted(verify_dataset(folder)) == ["grids.npy: missing", "stray.npy: not in the manifest"]


def test_the_id_is_the_content_s_and_a_name_means_the_newest(tmp_path):
    first = _make(tmp_path)
    second = _make(tmp_path, payload=b"other scene bytes " * 50)
    assert first.name != second.name, "two contents, one id"
    assert _make(tmp_path) == first, "the same content has the same id (and is not written twice)"
    assert resolve_ref("pins", tmp_path) == second, "`name` resolves to the newest dataset of that name"
    assert resolve_ref(f"pins@{first.name[:6]}", tmp_path) == first
