"""The local dataset registry: content ids, manifests, references, verification (docs/design.md section 5).

A dataset lives in `<root>/<name>/<id>/` (root: `datasets/` or `$SAMP_DATASETS_DIR`) and holds data files
plus `manifest.json`. `id` is the first 12 hex digits of sha256 over the sorted (relative path, file
sha256) pairs of its data files. A dataset is assembled in a temporary folder and renamed into place
when complete; a finished dataset folder is never modified.

The manifest itself is covered by `manifest_sha256` (format version 2): sha256 of its canonical JSON
without that key, so an edited count, split or file entry is caught by `verify` and refused by every
reader. Manifests of format version 1 carry no such hash and stay readable: their counts are checked
against the scene files when the dataset is opened or verified. The manifest's version and the scene
files' (`SCENE_FILE_VERSION`) are counted apart: a manifest of either version describes the same scene
files, so a dataset id does not depend on the manifest's version.
"""

from __future__ import annotations

import hashlib
import json
import shutil
from datetime import datetime, timezone
from pathlib import Path

from samp.cli import paste
from samp.paths import check_name, env_folder, file_sha256, inside

__all__ = ["FORMAT_VERSION", "MANIFEST", "READABLE_VERSIONS", "SCENE_FILE_VERSION", "DatasetError", "content_id",
           "datasets_root", "file_problems", "finalize_dataset", "list_datasets", "manifest_hash", "read_manifest",
           "recreate_hint", "resolve_ref", "verify_dataset"]

FORMAT_VERSION = 2  # of the manifest; 2 added manifest_sha256
READABLE_VERSIONS = (1, 2)
# The `format_version` inside each scene file's metadata. 2: waypoints timed as the robot would move, /tf,
# /robot and /ee_path for viewers, embedded mesh obstacles, voxel grids centred on the anchors (new ids);
# files of format 1 are read as before (samp/data/mcap_io.py).
# 3: episodes record `detour` (the straight line from start to goal is blocked), and the expert's numerics
# changed (float64 numpy FK in the collision checks and the IK), so the same spec gives other bytes (new ids).
SCENE_FILE_VERSION = 3
MANIFEST = "manifest.json"
MANIFEST_HASH = "manifest_sha256"
ID_LENGTH = 12
MAX_MANIFEST_BYTES = 256 << 20  # a manifest is read whole; the paper's dataset's is a few MB


class DatasetError(ValueError):
    """A dataset reference, manifest or file that is not what it should be."""


def datasets_root() -> Path:
    """`$SAMP_DATASETS_DIR`, else `datasets/` in the project folder (`samp.paths.project_dir`)."""
    from samp.paths import project_dir

    return env_folder("SAMP_DATASETS_DIR", lambda: project_dir() / "datasets")


def content_id(files: dict[str, str]) -> str:
    """First 12 hex digits of sha256 over the sorted (relative path, sha256) pairs."""
    h = hashlib.sha256()
    for rel in sorted(files):
        h.update(f"{rel}\0{files[rel]}\n".encode())
    return h.hexdigest()[:ID_LENGTH]


def manifest_hash(manifest: dict) -> str:
    """sha256 of the manifest's canonical JSON (sorted keys, no spaces), its own hash left out."""
    body = {k: v for k, v in manifest.items() if k != MANIFEST_HASH}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def recreate_hint(folder: Path, manifest: dict | None = None, how: str | None = None) -> str:
    """What to do about a damaged dataset: restore it, or make it again (`how`; default: generate it from
    its spec)."""
    name = (manifest or {}).get("name") or folder.parent.name
    how = how or (f"generate it again with `{paste('python -m samp.data generate', dataset=name)}` (the spec it was made "
                  f"from is under 'config' in its {MANIFEST})")
    return f"restore {folder} from a copy, or delete it and {how}"


def _data_files(folder: Path) -> list[Path]:
    from samp.data.card import CARD

    return sorted(p for p in folder.rglob("*") if p.is_file() and p.name not in (MANIFEST, CARD))


def finalize_dataset(tmp: Path, name: str, manifest: dict, root: Path | None = None) -> Path:
    """Hash the data files in `tmp`, write its manifest, and rename it to `<root>/<name>/<id>/`.

    If a dataset with the same id exists, its content is identical by construction: `tmp` is removed
    and the existing folder returned, so nothing is overwritten. An existing one that is damaged (its
    manifest or a file's sha256) is not returned as the new dataset: DatasetError naming it and the fix.
    """
    check_name(name, "dataset name")
    root = Path(root) if root else datasets_root()
    files = {p.relative_to(tmp).as_posix(): {"size": p.stat().st_size, "sha256": file_sha256(p)}
             for p in _data_files(tmp)}
    if not files:
        raise DatasetError(f"{tmp} holds no data files; nothing to finalize")
    ident = content_id({rel: f["sha256"] for rel, f in files.items()})
    full = {"format_version": FORMAT_VERSION, "name": name, "id": ident,
            # to the microsecond: `name` means the newest, and two datasets of a name can be finalized within
            # a second (a small spec regenerated); a stamp to the second then tied and the older could win
            "created": datetime.now(timezone.utc).isoformat(timespec="microseconds"), **manifest, "files": files}
    full[MANIFEST_HASH] = manifest_hash(full)
    (tmp / MANIFEST).write_text(json.dumps(full, indent=2, sort_keys=True))
    from samp.data.card import CARD, dataset_card

    (tmp / CARD).write_text(dataset_card(full))  # for people; like the manifest, not a hashed data file
    dest = root / name / ident
    dest.parent.mkdir(parents=True, exist_ok=True)
    try:
        if dest.exists():
            raise FileExistsError(dest)
        tmp.rename(dest)
    except OSError:
        if not (dest / MANIFEST).is_file():  # not a concurrent writer of the same content: a real failure
            raise
        _refuse_damaged(dest, name)
        shutil.rmtree(tmp)
    return dest


def _refuse_damaged(dest: Path, name: str) -> None:
    """DatasetError when the dataset already at `dest` (the id just made) is damaged: the caller's intact
    copy would otherwise be dropped for it."""
    try:
        problems = file_problems(dest, read_manifest(dest, check_sizes=False))
    except DatasetError as err:
        problems = [str(err).split("; ")[0]]
    if problems:
        raise DatasetError(f"a dataset {name}@{dest.name} is here already and damaged ({dest}: {problems[0]}); the "
                           "copy just made is not put in its place. Move the damaged one aside (or delete it) and "
                           "run the same command again")


def read_manifest(folder: Path, check_sizes: bool = True) -> dict:
    """The manifest of a dataset folder, after checking its format version, its own hash (version 2),
    that every file it names lies inside the folder, and (cheaply) the files' sizes. A DatasetError names
    the file, what was expected and what was found, and what to do."""
    folder = Path(folder)
    path = folder / MANIFEST
    if not path.is_file():
        raise DatasetError(f"{folder} is not a dataset: it has no {MANIFEST}")
    if path.stat().st_size > MAX_MANIFEST_BYTES:  # read whole: a size no dataset of ours comes near
        raise DatasetError(f"{path} has {path.stat().st_size} bytes, more than the {MAX_MANIFEST_BYTES} a manifest "
                           f"may have; it is not a samp manifest. {recreate_hint(folder)}")
    try:
        manifest = json.loads(path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise DatasetError(f"{path} is not valid JSON ({err}); {recreate_hint(folder)}") from None
    if not isinstance(manifest, dict):
        raise DatasetError(f"{path} holds a JSON {type(manifest).__name__}, not a manifest (an object); "
                           f"{recreate_hint(folder)}")
    version = manifest.get("format_version")
    if version not in READABLE_VERSIONS:
        raise DatasetError(f"{path} has format version {version!r}; this samp reads versions {READABLE_VERSIONS}. "
                           "Regenerate the dataset or use a matching samp version.")
    if version >= 2:
        said, actual = manifest.get(MANIFEST_HASH), manifest_hash(manifest)
        if said != actual:
            raise DatasetError(f"{path} was changed after the dataset was written: {MANIFEST_HASH} expected "
                               f"{said}, actual {actual} (an edited count, split or file entry); "
                               f"{recreate_hint(folder, manifest)}")
    if not isinstance(manifest.get("files"), dict):
        raise DatasetError(f"{path} has no 'files' table; {recreate_hint(folder, manifest)}")
    try:
        for rel in [*manifest["files"], *(s.get("file", "") for s in manifest.get("scenes", []))]:
            inside(folder, rel, f"{path}: file entry")
    except ValueError as err:
        raise DatasetError(f"{err}; {recreate_hint(folder, manifest)}") from None
    if check_sizes:
        for rel, info in manifest["files"].items():
            f = folder / rel
            if not f.is_file():
                raise DatasetError(f"dataset {folder}: file {rel} is missing; {recreate_hint(folder, manifest)}")
            if f.stat().st_size != info["size"]:
                raise DatasetError(f"dataset {folder}: file {rel} has {f.stat().st_size} bytes, the manifest says "
                                   f"{info['size']}; it is truncated or changed. {recreate_hint(folder, manifest)}")
    return manifest


def list_datasets(root: Path | None = None) -> list[dict]:
    """Every finished dataset under `root`: manifests (without the file lists) plus their paths."""
    root = Path(root) if root else datasets_root()
    out = []
    for manifest_path in sorted(root.glob(f"*/*/{MANIFEST}")):
        folder = manifest_path.parent
        if folder.name.startswith(".") or folder.parent.name.startswith("."):  # .tmp-* of an unfinished write
            continue
        try:
            m = read_manifest(folder, check_sizes=False)
        except DatasetError as err:  # listed, marked damaged: `open` and `verify` say what is wrong
            try:
                raw = json.loads(manifest_path.read_text())
            except (json.JSONDecodeError, UnicodeDecodeError):
                raw = {}
            raw = raw if isinstance(raw, dict) else {}
            out.append({"name": folder.parent.name, "id": folder.name, "created": str(raw.get("created", "")),
                        "path": str(folder), "damaged": str(err)})
            continue
        out.append({**{k: v for k, v in m.items() if k != "files"}, "path": str(folder)})
    return out


def resolve_ref(ref: str | Path, root: Path | None = None, lock: bool = True) -> Path:
    """`name` (newest, or the id a lock file pins: samp/data/lock.py), `name@id` (an id prefix is enough when
    unique), a folder path, or a remote reference `<remote>/datasets/NAME@ID` (pulled into `root` first,
    samp/data/sharing.py) -> the dataset folder. `lock=False` ignores the lock file."""
    root = Path(root) if root else datasets_root()
    path = Path(ref)
    if (path / MANIFEST).is_file():
        return path
    if isinstance(ref, str) and "://" in ref:
        from samp.data.sharing import pull_dataset

        return pull_dataset(ref, root=root)[0]
    name, _, ident = str(ref).partition("@")
    pinned = _locked(name, root) if lock and not ident else None
    if pinned:
        return pinned
    candidates = [d for d in list_datasets(root) if d["name"] == name and d["id"].startswith(ident)]
    if not candidates:
        available = sorted({f"{d['name']}@{d['id']}" for d in list_datasets(root)})
        raise DatasetError(f"no dataset {ref!r} under {root}; available: {', '.join(available) or 'none'} "
                           "(generate one with `python -m samp.data generate +dataset=NAME`)")
    if ident and len({d["id"] for d in candidates}) > 1:
        raise DatasetError(f"dataset id prefix {ref!r} is ambiguous: {[d['id'] for d in candidates]}")
    return Path(max(candidates, key=lambda d: d["created"])["path"])


def _locked(name: str, root: Path) -> Path | None:
    """The folder of the id the lock file in effect pins for the bare `name` (None: not pinned); a pinned
    id that is not under `root` is a DatasetError saying how to get it."""
    from samp.data.lock import locked

    pin = locked("datasets", name)
    if pin is None:
        return None
    ref, lock_path = pin
    found = [d for d in list_datasets(root) if f"{d['name']}@{d['id']}" == ref]
    if found:
        return Path(found[0]["path"])
    raise DatasetError(f"dataset {name!r} is pinned to {ref} by the lock file {lock_path}, and {ref} is not under "
                       f"{root}: pull it (`python -m samp.data pull dataset={ref} remote=URL`), or generate it from the "
                       f"spec it was made from, or write the lock again (`python -m samp.train experiment=NAME --lock`)")


def file_problems(folder: Path, manifest: dict) -> list[str]:
    """Re-hash every file the manifest lists: one line per file (its path relative to `folder`) that is
    missing, differs (expected vs actual sha256) or is not listed, and one if the id does not match."""
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
    ident = content_id({r: i["sha256"] for r, i in manifest["files"].items()})
    if not problems and ident != manifest.get("id"):
        problems.append(f"{MANIFEST}: id expected {ident} (from its file list), the manifest says {manifest.get('id')}")
    return problems


def verify_dataset(folder: Path) -> list[str]:
    """Everything `open_dataset` checks, in full: the manifest (format, its own hash, file entries inside
    the folder), every file's sha256, and what each scene file holds against the manifest's counts.
    Returns one line per problem (empty when the dataset is intact)."""
    try:
        manifest = read_manifest(folder, check_sizes=False)
    except DatasetError as err:
        return [str(err)]
    problems = file_problems(Path(folder), manifest)
    if not problems and "scenes" in manifest:
        from samp.data.dataset import scene_count_problems  # decodes the scene files (no grids)

        problems = scene_count_problems(Path(folder), manifest)
    return problems
