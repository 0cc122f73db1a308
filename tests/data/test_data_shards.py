"""Sharded generation: shard 0 of 2 then shard 1 of 2 (which merges) gives the dataset an unsharded run gives,
file for file, under the same content id; a shard alone merges nothing."""

from __future__ import annotations

import json

import pytest

from samp.data import generate
from samp.data.generation import work_dir
from samp.data.spec import load_spec

pytestmark = pytest.mark.slow  # plans three datasets' worth of a tiny spec

SPEC = {"name": "sharded", "robot": "panda", "seed": 3, "train_scenes": 2, "val_scenes": 1, "test_scenes": 0,
        "trajectories_per_scene": 1, "eval_problems_per_scene": 1, "generators": ["tabletop"], "resolutions": [8]}


def _files(folder) -> dict:
    """{file name: sha256} from the dataset's manifest."""
    manifest = json.loads((folder / "manifest.json").read_text())
    files = manifest.get("files") or manifest.get("sha256")
    assert isinstance(files, dict) and files, f"the manifest lists no file hashes: {sorted(manifest)}"
    return {name: (entry["sha256"] if isinstance(entry, dict) else entry) for name, entry in files.items()}


def test_two_shards_make_the_unsharded_dataset(tmp_path):
    """Catches shards that skip or repeat a scene (index % num_shards), seeds that depend on the shard, or a
    merge that names the dataset by how it was made rather than by its content."""
    assert generate(SPEC, shard=0, num_shards=2, root=tmp_path / "sharded", progress=False) is None, \
        "shard 0 of 2 alone must not merge"
    work = work_dir(load_spec(SPEC), tmp_path / "sharded")
    assert sorted(p.name for p in work.glob("scene_*.mcap")) == ["scene_0000.mcap", "scene_0002.mcap"], \
        "shard 0 of 2 holds the even scenes"
    sharded = generate(SPEC, shard=1, num_shards=2, root=tmp_path / "sharded", progress=False)
    whole = generate(SPEC, root=tmp_path / "whole", progress=False)
    assert sharded is not None and whole is not None
    assert sharded.name == whole.name, f"content ids differ: {sharded.name} vs {whole.name}"
    assert _files(sharded) == _files(whole), "the scene files differ between sharded and unsharded generation"
