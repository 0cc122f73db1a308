"""Folders on a remote, stored by content: the transfer under `samp.data push|pull` and `samp.runs push|pull`
(docs/design.md, "Remotes").

A remote is any fsspec URL (`file:///srv/samp`, `s3://bucket/team`, `hf://datasets/org/repo`). Under it:

    blobs/sha256/<first two hex digits>/<sha256>     every file, named by the sha256 of its bytes
    <kind>/<entry>/index.json                        what one entry (a dataset, a run) holds

`index.json` maps each file's path inside the entry to its sha256 and size, and carries `index_sha256`,
the sha256 of its own canonical JSON without that key. A push uploads the blobs first and the index last,
so an entry whose index exists is complete; a blob already there whose bytes hash to its name is not sent
again (an interrupted push continues where it stopped), and one whose bytes do not (damaged, or cut short
by a killed upload) is uploaded anew: a push reads back every blob it keeps, once. A pull downloads into a staging folder the caller
names, checks every file's sha256 as it arrives, keeps what is already there and verified (an interrupted
pull continues), and never publishes: the caller verifies the whole and renames the folder into place.

Credentials and endpoints are the file system's own: for s3:// the standard AWS variables
(`AWS_ACCESS_KEY_ID`, `AWS_SECRET_ACCESS_KEY`, `AWS_ENDPOINT_URL` for a server other than AWS), or any
fsspec setting as `FSSPEC_<PROTOCOL>_<KEY>` (e.g. `FSSPEC_S3_ENDPOINT_URL`).
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from samp.paths import file_sha256, inside

__all__ = ["INDEX", "RemoteError", "blob_url", "join", "open_remote", "pull_folder", "push_folder", "read_index"]

INDEX = "index.json"
INDEX_FORMAT = 1
INDEX_HASH = "index_sha256"
BLOBS = "blobs/sha256"
EXTRAS = {"s3": "s3", "s3a": "s3", "hf": "hf"}  # protocol -> the pip extra that brings its file system


class RemoteError(ValueError):
    """A remote that cannot be reached or read, or whose content is not what its index says."""


def join(url: str, *parts: str) -> str:
    return "/".join([url.rstrip("/"), *(p.strip("/") for p in parts)])


def open_remote(url: str):
    """(fsspec file system, the path of `url` on it). A protocol whose package is missing is a RemoteError
    naming the pip extra that brings it."""
    import fsspec

    try:
        fs, path = fsspec.core.url_to_fs(url)
    except ImportError as err:
        protocol = url.split("://", 1)[0]
        extra = EXTRAS.get(protocol)
        hint = f"pip install 'samp[{extra}]'" if extra else "install the fsspec implementation of that protocol"
        raise RemoteError(f"remote {url}: {err}; {hint}") from None
    except ValueError as err:  # an unknown protocol
        raise RemoteError(f"remote {url}: {err}; give an fsspec URL such as file:///srv/samp or s3://bucket/samp") from None
    fs.invalidate_cache()  # listings cached by an earlier call in this process may be stale
    return fs, path


def blob_url(root: str, sha256: str) -> str:
    return join(root, BLOBS, sha256[:2], sha256)


def _index_hash(index: dict) -> str:
    body = {k: v for k, v in index.items() if k != INDEX_HASH}
    return hashlib.sha256(json.dumps(body, sort_keys=True, separators=(",", ":")).encode()).hexdigest()


def _holds(fs, path: str, info: dict) -> bool:
    """Whether the remote file `path` holds the bytes `info` ({"sha256", "size"}) names: its size, then the
    sha256 of its bytes, read back (the size alone would keep a same-size damaged blob; no file system
    here reports a sha256 of its own for every file)."""
    try:
        if int(fs.info(path)["size"]) != info["size"]:
            return False
        digest = hashlib.sha256()
        with fs.open(path, "rb") as f:
            for chunk in iter(lambda: f.read(1 << 20), b""):
                digest.update(chunk)
    except FileNotFoundError:
        return False
    return digest.hexdigest() == info["sha256"]


def push_folder(folder: Path, files: dict[str, dict], root: str, entry: str, meta: dict,
                force: bool = False) -> tuple[int, int]:
    """Upload `files` ({path inside `folder`: {"sha256", "size"}}, already verified by the caller) as blobs
    under the remote `root`, then the index of `entry` (a path below `root`, e.g. "datasets/NAME@ID")
    with `meta` beside the file table. A blob already there whose bytes hash to its sha256 is kept unless
    `force` (every blob uploaded anew); any other is replaced. Returns (files uploaded, files already there)."""
    fs, root_path = open_remote(root)
    sent = kept = 0
    for rel, info in sorted(files.items()):
        blob = blob_url(root_path, info["sha256"])
        if not force and _holds(fs, blob, info):
            kept += 1
            continue
        fs.makedirs(blob.rsplit("/", 1)[0], exist_ok=True)
        fs.put_file(str(folder / rel), blob)
        sent += 1
    index = {"format_version": INDEX_FORMAT, **meta, "files": {rel: {"sha256": i["sha256"], "size": i["size"]}
                                                               for rel, i in files.items()}}
    index[INDEX_HASH] = _index_hash(index)
    where = join(root_path, entry)
    fs.makedirs(where, exist_ok=True)
    fs.pipe_file(join(where, INDEX), json.dumps(index, indent=2, sort_keys=True).encode())
    return sent, kept


def read_index(root: str, entry: str) -> dict:
    """The index of `entry` under the remote `root`, after checking its format, its own hash and that every
    path it names stays inside the entry. RemoteError when it is missing or damaged."""
    fs, root_path = open_remote(root)
    url = join(root, entry, INDEX)
    try:
        raw = fs.cat_file(join(root_path, entry, INDEX))
    except FileNotFoundError:
        raise RemoteError(f"nothing at {join(root, entry)}: it has no {INDEX} (never pushed, or the push did not "
                          "finish; push it again)") from None
    try:
        index = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise RemoteError(f"{url} is not valid JSON ({err}); push the entry again") from None
    if not isinstance(index, dict) or index.get("format_version") != INDEX_FORMAT or not isinstance(index.get("files"), dict):
        raise RemoteError(f"{url} is not an index of format version {INDEX_FORMAT}; push the entry again, or use a "
                          "samp version that reads it")
    if index.get(INDEX_HASH) != _index_hash(index):
        raise RemoteError(f"{url} was changed after it was pushed: {INDEX_HASH} expected {index.get(INDEX_HASH)}, "
                          f"actual {_index_hash(index)}; push the entry again")
    return index


def pull_folder(root: str, entry: str, index: dict, staging: Path) -> tuple[int, int]:
    """Download the files of `index` (from `read_index(root, entry)`) into `staging`, each checked against its
    sha256 before it takes its name there; a file already in `staging` with the right sha256 is kept, and
    a file there that the index does not name is removed. RemoteError naming the file when a blob is
    missing or its bytes differ (the bad download is deleted). Returns (files downloaded, files kept)."""
    fs, root_path = open_remote(root)
    staging.mkdir(parents=True, exist_ok=True)
    got = kept = 0
    for rel, info in sorted(index["files"].items()):
        try:
            dest = inside(staging, rel, f"{join(root, entry, INDEX)}: file entry")
        except ValueError as err:
            raise RemoteError(str(err)) from None
        if dest.is_file() and dest.stat().st_size == info["size"] and file_sha256(dest) == info["sha256"]:
            kept += 1
            continue
        dest.parent.mkdir(parents=True, exist_ok=True)
        part = dest.with_name(dest.name + ".part")
        blob = blob_url(root_path, info["sha256"])
        try:
            fs.get_file(blob, str(part))
        except FileNotFoundError:
            raise RemoteError(f"remote file {rel} of {join(root, entry)} is missing (its blob {blob_url(root, info['sha256'])} "
                              "is not there); push the entry again") from None
        actual = file_sha256(part)
        if actual != info["sha256"]:
            part.unlink()
            raise RemoteError(f"remote file {rel} of {join(root, entry)} is damaged: sha256 expected {info['sha256']}, "
                              f"actual {actual} ({blob_url(root, info['sha256'])}); nothing was published locally. "
                              "Push it again from an intact copy (a push replaces every blob whose bytes differ)")
        part.replace(dest)
        got += 1
    wanted = {(staging / rel).resolve() for rel in index["files"]}
    for stray in [p for p in staging.rglob("*") if p.is_file() and p.resolve() not in wanted]:
        stray.unlink()  # a `.part` of an interrupted download, or a file of another try: not ours to publish
    return got, kept
