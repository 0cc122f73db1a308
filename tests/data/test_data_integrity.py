"""Every read checks integrity (docs/design.md section 7; issue 21): a flipped byte in a scene file, an edited
manifest (counts, splits, a per-scene count, a file entry outside the folder) and a dataset name that
would leave the datasets root are refused by `open_dataset` exactly when `verify` refuses them, with the
file named and what to do."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys

import pytest
from mcap.reader import make_reader

from samp.data import DatasetError, generate, open_dataset, read_manifest, verify_dataset, write_dataset
from samp.data.mcap_io import _grid_from_voxels, read_scene_file
from samp.data.registry import manifest_hash

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SMALL = {"name": "small", "robot": "panda", "seed": 3, "train_scenes": 1, "val_scenes": 1, "test_scenes": 0,
         "trajectories_per_scene": 2, "eval_problems_per_scene": 1, "generators": ["tabletop"], "resolutions": [10]}


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp("datasets")
    return generate(SMALL, root=root, progress=False)


@pytest.fixture
def copy(small, tmp_path):
    return shutil.copytree(small, tmp_path / "small" / small.name)


def _edit_manifest(folder, edit, rehash: bool) -> None:
    path = folder / "manifest.json"
    manifest = json.loads(path.read_text())
    edit(manifest)
    if rehash:  # a forger who also recomputes the manifest's own hash
        manifest["manifest_sha256"] = manifest_hash(manifest)
    path.write_text(json.dumps(manifest, indent=2, sort_keys=True))


def _grids_without_crc(path, n_e: int):
    """The grid as a reader that skips CRCs decodes it (None when even that fails)."""
    from foxglove_schemas_protobuf.VoxelGrid_pb2 import VoxelGrid

    try:
        with open(path, "rb") as f:
            for _, _, m in make_reader(f, validate_crcs=False).iter_messages(topics=[f"/sdf/n{n_e}"]):
                return _grid_from_voxels(VoxelGrid.FromString(m.data))
    except Exception:  # noqa: BLE001 - any failure means this flip is caught without CRCs too
        return None


def test_flipped_byte_is_refused_by_open_and_by_the_crc(copy, small):
    """Find a byte whose flip still decodes to a different grid without CRC checks (what reached training
    before), then check that both the reader (CRC) and `open_dataset` (sha256) refuse it."""
    target = copy / "scene_0000.mcap"
    original = target.read_bytes()
    exact = read_scene_file(small / "scene_0000.mcap", resolutions=[10]).grids[10]
    # zstd chunks rarely decode when flipped; search the whole file for a flip that silently changes data
    silent = None
    for offset in range(len(original) // 3, len(original)):
        data = bytearray(original)
        data[offset] ^= 0x10
        target.write_bytes(bytes(data))
        grid = _grids_without_crc(target, 10)
        if grid is not None and not bool((grid == exact).all()):
            silent = offset
            break
    assert silent is not None, "no single-byte flip decodes to a different grid without CRC checks"
    with pytest.raises(ValueError, match=r"scene_0000.mcap is not a readable samp scene file .*CRC|crc"):
        read_scene_file(target, resolutions=[10])
    with pytest.raises(DatasetError, match=r"scene_0000.mcap: sha256 expected [0-9a-f]{64}, actual [0-9a-f]{64}.*"
                                           r"generate dataset=small"):
        open_dataset(copy)
    assert verify_dataset(copy)[0].startswith("scene_0000.mcap: sha256 expected")


@pytest.mark.parametrize("edit", [
    lambda m: m["counts"].update(trajectories=m["counts"]["trajectories"] + 5),
    lambda m: m["splits"].update(train=m["splits"]["train"] + m["splits"]["val"], val=[]),
    lambda m: m["scenes"][0].update(trajectories=m["scenes"][0]["trajectories"] - 1),
], ids=["counts", "splits", "scene-count"])
def test_edited_manifest_is_caught_by_verify_and_refused_by_open(copy, edit):
    _edit_manifest(copy, edit, rehash=False)
    problems = verify_dataset(copy)
    assert len(problems) == 1 and "was changed after the dataset was written: manifest_sha256 expected" in problems[0]
    with pytest.raises(DatasetError, match=r"manifest.json was changed after the dataset was written"):
        open_dataset(copy)
    out = subprocess.run([sys.executable, "-m", "samp.data", "ls", f"root={copy.parent.parent}"],
                         capture_output=True, text=True, timeout=300)
    assert f"small@{copy.name}" in out.stdout and "DAMAGED" in out.stdout, out.stdout + out.stderr
    verified = subprocess.run([sys.executable, "-m", "samp.data", "verify", str(copy)], capture_output=True, text=True,
                              timeout=300)
    assert verified.returncode == 1 and "manifest_sha256 expected" in verified.stderr


def test_per_scene_count_edited_even_with_a_recomputed_hash_is_refused(copy):
    """The counts are also checked against what each file holds: verify and open agree."""
    _edit_manifest(copy, lambda m: m["scenes"][1].update(episodes=m["scenes"][1]["episodes"] + 1), rehash=True)
    (problem,) = verify_dataset(copy)
    assert "scene_0001.mcap: the manifest says" in problem and "the file holds" in problem
    with pytest.raises(DatasetError, match=r"scene_0001.mcap: the manifest says .* the file holds"):
        open_dataset(copy)


def test_format_version_1_manifest_still_opens_and_counts_are_checked(copy, small):
    """A manifest written before the manifest hash (format version 1) opens as before; its counts are
    checked against the files, so an edited per-scene count is still refused."""
    def to_v1(m):
        m["format_version"] = 1
        m.pop("manifest_sha256")

    _edit_manifest(copy, to_v1, rehash=False)
    assert verify_dataset(copy) == []
    assert len(open_dataset(copy)) == len(open_dataset(small))
    _edit_manifest(copy, lambda m: m["scenes"][0].update(trajectories=0), rehash=False)
    assert "scene_0000.mcap: the manifest says" in verify_dataset(copy)[0]
    with pytest.raises(DatasetError, match="scene_0000.mcap: the manifest says"):
        open_dataset(copy)


def test_manifest_entries_outside_the_folder_are_refused(copy, tmp_path):
    outside = tmp_path / "secret.mcap"
    shutil.copy(copy / "scene_0000.mcap", outside)

    def escape(m):
        m["scenes"][0]["file"] = "../../secret.mcap"
        m["files"]["../../secret.mcap"] = m["files"].pop("scene_0000.mcap")

    _edit_manifest(copy, escape, rehash=True)
    with pytest.raises(DatasetError, match=r"file entry: '../../secret.mcap' must be a path inside"):
        open_dataset(copy)
    assert "must be a path inside" in verify_dataset(copy)[0]


@pytest.mark.parametrize("name", ["..", ".", "a/b", "../../x", ".hidden", ""])
def test_dataset_names_cannot_leave_the_root(small, tmp_path, name):
    root = tmp_path / "root"
    root.mkdir()
    if name:  # write_dataset(name="") keeps the dataset's own name
        with pytest.raises(ValueError, match="not a plain folder name"):
            write_dataset(open_dataset(small), name=name, root=root)
    with pytest.raises(ValueError, match="name must be a plain folder name"):
        generate({**SMALL, "name": name}, root=root, progress=False)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["root"] and list(root.iterdir()) == []


def test_read_manifest_of_intact_dataset_has_its_hash(small):
    m = read_manifest(small)
    assert m["format_version"] == 2 and m["manifest_sha256"] == manifest_hash(m)
def test_the_newest_of_two_datasets_finalized_within_a_second_is_the_later(tmp_path):
    """`name` resolves to the newest dataset of that name, also when two were finalized within one second
    (a small spec edited and generated again at once): `created` is stamped to the microsecond. The later
    one is given the larger id, so a tie in the stamp would pick the earlier (the first in id order)."""
    import hashlib

    from samp.data.registry import content_id, finalize_dataset, resolve_ref

    ident = lambda content: content_id({"scene_0000.mcap": hashlib.sha256(content).hexdigest()})  # noqa: E731
    contents = sorted((b"first", b"second"), key=ident)
    made = []
    for i, content in enumerate(contents):
        work = tmp_path / f"work_{i}"
        work.mkdir()
        (work / "scene_0000.mcap").write_bytes(content)
        made.append(finalize_dataset(work, "twice", {}, root=tmp_path / "root"))
    assert made[0].name < made[1].name
    assert resolve_ref("twice", tmp_path / "root") == made[1]
