"""Datasets on a remote: `push_dataset`, `pull_dataset` and remote references (docs/datasets.md, "Sharing
datasets and policies"; the layout in docs/design.md, "Remotes").

A dataset `NAME@ID` lives on a remote as `<remote>/datasets/NAME@ID/index.json` plus the blobs of its
files (samp/remote.py): its data files, `manifest.json` and its card. A remote reference is the URL of
that entry, `s3://bucket/datasets/NAME@ID` (a unique id prefix is enough); `open_dataset` and
`dataset=` in configs take one, pull it into the local datasets folder once and open the local copy.

A pull is published only whole: the files arrive in `<root>/NAME/.pull-ID/`, each checked against the
sha256 the index gives; the folder is then verified as `python -m samp.data verify` would (the manifest's
own hash, every file against the manifest, the content id against `ID`) and renamed to `<root>/NAME/ID/`.
An interrupted pull leaves the hidden staging folder, which the next pull continues.

A dataset already here is verified first, as `verify` does: an intact one is "here already"; a damaged one
is repaired from the remote (its files that are intact are kept, the others downloaded and checked) and
the damaged copy is moved aside to `<root>/NAME/.damaged-ID-<time>/`, whole, with anything else that was
in its folder; nothing of it is deleted.
"""

from __future__ import annotations

import re
import shutil
import time
from pathlib import Path

from samp.data.registry import (ID_LENGTH, MANIFEST, DatasetError, datasets_root, file_problems, read_manifest, resolve_ref,
                                verify_dataset)
from samp.data.merging import link_or_copy
from samp.paths import check_name, file_sha256
from samp.remote import RemoteError, join, open_remote, pull_folder, push_folder, read_index

__all__ = ["DATASETS", "is_remote", "pull_dataset", "push_dataset", "remote_entry", "split_remote_ref"]

DATASETS = "datasets"  # the folder of dataset entries on a remote
_ENTRY = re.compile(rf"^(?P<root>.+?)/{DATASETS}/(?P<name>[^/@]+)@(?P<id>[0-9a-f]+)/?$")


def is_remote(ref) -> bool:
    """Whether a dataset reference is a URL (`s3://...`, `file:///...`), not a name or a local folder."""
    return isinstance(ref, str) and "://" in ref


def split_remote_ref(url: str) -> tuple[str, str, str]:
    """`<remote>/datasets/NAME@ID` -> (remote, NAME, ID prefix); ValueError saying the expected form."""
    m = _ENTRY.match(url)
    if not m:
        raise ValueError(f"{url!r} is not a remote dataset reference: give <remote>/{DATASETS}/NAME@ID, e.g. "
                         f"s3://bucket/{DATASETS}/quickstart@0123456789ab (a unique id prefix is enough)")
    return m["root"], m["name"], m["id"]


def remote_entry(remote: str, name: str, ident: str) -> str:
    """The full `NAME@ID` of the entry on `remote` whose id starts with `ident` (RemoteError: none or several)."""
    fs, path = open_remote(remote)
    try:
        entries = [p.rstrip("/").rsplit("/", 1)[-1] for p in fs.ls(join(path, DATASETS), detail=False)]
    except FileNotFoundError:
        entries = []
    found = sorted(e for e in entries if e.partition("@")[0] == name and e.partition("@")[2].startswith(ident))
    if len(found) != 1:
        have = sorted(e for e in entries if e.startswith(f"{name}@"))
        what = f"no dataset {name}@{ident}" if not found else f"dataset id prefix {name}@{ident} is ambiguous"
        raise RemoteError(f"{what} on {remote}; its {name} datasets: {', '.join(have) or 'none'}")
    return found[0]


def _hashed_files(folder: Path, manifest: dict) -> dict[str, dict]:
    """The manifest's data files plus the manifest and the card, {path: {"sha256", "size"}}."""
    from samp.data.card import CARD

    files = {rel: {"sha256": i["sha256"], "size": i["size"]} for rel, i in manifest["files"].items()}
    for rel in (MANIFEST, CARD):
        if (folder / rel).is_file():
            files[rel] = {"sha256": file_sha256(folder / rel), "size": (folder / rel).stat().st_size}
    return files


def push_dataset(ref: str | Path, remote: str, root: Path | None = None, force: bool = False) -> tuple[str, int, int]:
    """Verify the local dataset `ref` (a name, NAME@ID or folder) and upload it to `remote` (`force`: every
    file, also those already there, e.g. to replace a damaged one). Returns (the entry's URL, files
    uploaded, files already there)."""
    from samp.data.registry import verify_dataset

    folder = resolve_ref(ref, root)
    problems = verify_dataset(folder)
    if problems:
        raise DatasetError(f"dataset {folder} fails verification, so it is not pushed: {'; '.join(problems[:3])}")
    manifest = read_manifest(folder)
    entry = f"{DATASETS}/{manifest['name']}@{manifest['id']}"
    sent, kept = push_folder(folder, _hashed_files(folder, manifest), remote, entry,
                             {"kind": "dataset", "ref": f"{manifest['name']}@{manifest['id']}"}, force)
    return join(remote, entry), sent, kept


def pull_dataset(ref: str, remote: str | None = None, root: Path | None = None) -> tuple[Path, int, int]:
    """Pull `ref` (NAME@ID with `remote`, or a remote reference `<remote>/datasets/NAME@ID`) into the local
    datasets folder. Returns (the local folder, files downloaded, files kept); (folder, 0, 0) when that
    dataset is here already and intact. A damaged local copy is repaired from the remote and moved aside
    (module docstring); RemoteError naming the damage when the remote cannot repair it."""
    if is_remote(ref):
        remote, name, ident = split_remote_ref(ref)
    else:
        name, _, ident = str(ref).partition("@")
        if not remote or not ident:
            raise ValueError(f"say what to pull: dataset=NAME@ID remote=URL, or dataset=<remote>/{DATASETS}/NAME@ID "
                             f"(got dataset={ref!r}{f' remote={remote}' if remote else ''})")
    check_name(name, "dataset name")
    root = Path(root) if root else datasets_root()
    damage = _damage(root / name / ident) if len(ident) == ID_LENGTH else None
    if damage == []:
        return root / name / ident, 0, 0  # here already and intact: no need to reach the remote
    full = remote_entry(remote, name, ident)
    if full.partition("@")[2] != ident:  # an id prefix: the full id names the local folder
        ident = full.partition("@")[2]
        damage = _damage(root / name / ident)
        if damage == []:
            return root / name / ident, 0, 0
    dest = root / name / ident
    entry = f"{DATASETS}/{full}"
    staging = root / name / f".pull-{ident}"
    try:
        index = read_index(remote, entry)
        if damage:  # its intact files are kept (pull_folder re-hashes each), the others downloaded
            _seed(staging, dest, index)
        got, kept = pull_folder(remote, entry, index, staging)
        _check_pulled(staging, name, ident, index, join(remote, entry))
    except RemoteError as err:
        if not damage:
            raise
        raise RemoteError(f"dataset {name}@{ident} here ({dest}) is damaged ({_first(damage)}), and {err}") from None
    if damage:
        aside = root / name / f".damaged-{ident}-{time.strftime('%Y%m%d-%H%M%S')}"
        dest.rename(aside)
        print(f"dataset {name}@{ident} in {dest} was damaged ({_first(damage)}): repaired from {join(remote, entry)}; "
              f"the damaged copy is kept in {aside} (delete it once you have looked)", flush=True)
    try:
        staging.rename(dest)
    except OSError:
        if not (dest / MANIFEST).is_file():  # not a concurrent pull of the same dataset: a real failure
            raise
        shutil.rmtree(staging)
    return dest, got, kept


def _damage(folder: Path) -> list[str] | None:
    """What `verify` finds wrong with the local dataset `folder` ([] when intact), None when it is not here."""
    return verify_dataset(folder) if (folder / MANIFEST).is_file() else None


def _first(problems: list[str]) -> str:
    return problems[0] + (f" and {len(problems) - 1} more" if len(problems) > 1 else "")


def _seed(staging: Path, dest: Path, index: dict) -> None:
    """Hard links (copies where refused) in `staging` of the files of the damaged `dest` that `index` names."""
    for rel in index["files"]:
        src, dst = dest / rel, staging / rel
        if src.is_file() and not src.is_symlink() and not dst.exists():
            dst.parent.mkdir(parents=True, exist_ok=True)
            link_or_copy(src, dst)


def _check_pulled(staging: Path, name: str, ident: str, index: dict, url: str) -> None:
    """Refuse (RemoteError, nothing published) a pulled folder that is not the dataset NAME@ID, intact."""
    try:
        manifest = read_manifest(staging, check_sizes=False)  # the files are checked below, against the index
    except DatasetError as err:  # its advice (restore, regenerate) is for a local dataset: only the first part
        raise RemoteError(f"{url}: its {MANIFEST} is not intact ({str(err).split('; ')[0]}); nothing was published "
                          "locally. Push the dataset again from an intact copy") from None
    if (manifest.get("name"), manifest.get("id")) != (name, ident):
        raise RemoteError(f"{url} holds the manifest of {manifest.get('name')}@{manifest.get('id')}, not {name}@{ident}; "
                          "push the dataset again")
    missing = sorted(set(manifest["files"]) - set(index["files"]))
    problems = [f"{rel}: not in {url}'s index" for rel in missing] or file_problems(staging, manifest)
    if problems:
        raise RemoteError(f"{url} is not the dataset its manifest describes: {'; '.join(problems[:3])}; nothing was "
                          "published locally. Push the dataset again from an intact copy")
