"""The local dataset registry: content ids, manifests, references, verification (DESIGN section 5).

A dataset lives in `<root>/<name>/<id>/` (root: `datasets/` or `$SAMP_DATASETS_DIR`) and holds data files
plus `manifest.json`. `id` is the first 12 hex digits of sha256 over the sorted (relative path, file
sha256) pairs of its data files. A dataset is assembled in a temporary folder and renamed into place
when complete; a finished dataset folder is never modified.
"""

from __future__ import annotations

import hashlib
import json
import os
import shutil
from datetime import datetime, timezone
from pathlib import Path

from samp.paths import REPO_ROOT
from samp.paths import file_sha256

__all__ = ["FORMAT_VERSION", "MANIFEST", "DatasetError", "content_id", "datasets_root", "finalize_dataset",
           "list_datasets", "read_manifest", "resolve_ref", "verify_dataset"]

FORMAT_VERSION = 1
MANIFEST = "manifest.json"
ID_LENGTH = 12


class DatasetError(ValueError):
    """A dataset reference, manifest or file that is not what it should be."""


def datasets_root() -> Path:
    return Path(os.environ.get("SAMP_DATASETS_DIR", REPO_ROOT / "datasets"))


def content_id(files: dict[str, str]) -> str:
    """First 12 hex digits of sha256 over the sorted (relative path, sha256) pairs."""
    h = hashlib.sha256()
    for rel in sorted(files):
        h.update(f"{rel}\0{files[rel]}\n".encode())
    return h.hexdigest()[:ID_LENGTH]


def _data_files(folder: Path) -> list[Path]:
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.name != MANIFEST)


def finalize_dataset(tmp: Path, name: str, manifest: dict, root: Path | None = None) -> Path:
    """Hash the data files in `tmp`, write its manifest, and rename it to `<root>/<name>/<id>/`.

    If a dataset with the same id exists, its content is identical by construction: `tmp` is removed
    and the existing folder returned, so nothing is overwritten.
    """
    root = Path(root) if root else datasets_root()
    files = {p.relative_to(tmp).as_posix(): {"size": p.stat().st_size, "sha256": file_sha256(p)}
             for p in _data_files(tmp)}
    if not files:
        raise DatasetError(f"{tmp} holds no data files; nothing to finalize")
    ident = content_id({rel: f["sha256"] for rel, f in files.items()})
    full = {"format_version": FORMAT_VERSION, "name": name, "id": ident,
            "created": datetime.now(timezone.utc).isoformat(timespec="seconds"), **manifest, "files": files}
    (tmp / MANIFEST).write_text(json.dumps(full, indent=2, sort_keys=True))
    dest = root / name / ident
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        if dest.exists():
            raise FileExistsError(dest)
        tmp.rename(dest)
    except OSError:
        if not (dest / MANIFEST).is_file():  # not a concurrent writer of the same content: a real failure
            raise
        shutil.rmtree(tmp)
    return dest


def read_manifest(folder: Path, check_sizes: bool = True) -> dict:
    """The manifest of a dataset folder, after checking its format version and (cheaply) file sizes."""
    path = folder / MANIFEST
    if not path.is_file():
        raise DatasetError(f"{folder} is not a dataset: it has no {MANIFEST}")
    try:
        manifest = json.loads(path.read_text())
    except json.JSONDecodeError as err:
        raise DatasetError(f"{path} is not valid JSON ({err})") from None
    version = manifest.get("format_version")
    if version != FORMAT_VERSION:
        raise DatasetError(f"{path} has format version {version!r}; this samp reads version {FORMAT_VERSION}. "
                           "Regenerate the dataset or use a matching samp version.")
    if check_sizes:
        for rel, info in manifest["files"].items():
            f = folder / rel
            if not f.is_file():
                raise DatasetError(f"dataset {folder}: file {rel} is missing")
            if f.stat().st_size != info["size"]:
                raise DatasetError(f"dataset {folder}: file {rel} has {f.stat().st_size} bytes, the manifest says "
                                   f"{info['size']}; it is truncated or changed (run `python -m samp.data verify`)")
    return manifest


def list_datasets(root: Path | None = None) -> list[dict]:
    """Every finished dataset under `root`: manifests (without the file lists) plus their paths."""
    root = Path(root) if root else datasets_root()
    out = []
    for manifest_path in sorted(root.glob(f"*/*/{MANIFEST}")):
        try:
            m = read_manifest(manifest_path.parent, check_sizes=False)
        except DatasetError:
            continue
        out.append({**{k: v for k, v in m.items() if k != "files"}, "path": str(manifest_path.parent)})
    return out


def resolve_ref(ref: str | Path, root: Path | None = None) -> Path:
    """`name` (newest), `name@id` (an id prefix is enough when unique) or a folder path -> the dataset folder."""
    root = Path(root) if root else datasets_root()
    path = Path(ref)
    if (path / MANIFEST).is_file():
        return path
    name, _, ident = str(ref).partition("@")
    candidates = [d for d in list_datasets(root) if d["name"] == name and d["id"].startswith(ident)]
    if not candidates:
        available = sorted({f"{d['name']}@{d['id']}" for d in list_datasets(root)})
        raise DatasetError(f"no dataset {ref!r} under {root}; available: {', '.join(available) or 'none'} "
                           "(generate one with `python -m samp.data generate +dataset=NAME`)")
    if ident and len({d["id"] for d in candidates}) > 1:
        raise DatasetError(f"dataset id prefix {ref!r} is ambiguous: {[d['id'] for d in candidates]}")
    return Path(max(candidates, key=lambda d: d["created"])["path"])


def verify_dataset(folder: Path) -> list[str]:
    """Re-hash every file; returns one line per problem (empty when the dataset is intact)."""
    manifest = read_manifest(folder, check_sizes=False)
    problems = []
    for rel, info in sorted(manifest["files"].items()):
        f = folder / rel
        if not f.is_file():
            problems.append(f"{rel}: missing")
            continue
        actual = file_sha256(f)
        if actual != info["sha256"]:
            problems.append(f"{rel}: sha256 expected {info['sha256']}, actual {actual}")
    extra = {p.relative_to(folder).as_posix() for p in _data_files(folder)} - set(manifest["files"])
    problems += [f"{rel}: not in the manifest" for rel in sorted(extra)]
    if not problems and content_id({r: i["sha256"] for r, i in manifest["files"].items()}) != manifest["id"]:
        problems.append(f"manifest id {manifest['id']} does not match its file list")
    return problems
