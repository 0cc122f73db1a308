"""One config tree from several folders: the user's folders of `SAMP_CONFIG_PATH` in front of samp's own.

Hydra composes from one primary folder, and the rest of samp reads `conf_dir()/group/name.yaml` directly
(robots, scenes, expert settings, the help texts). So instead of teaching every reader a search path, the
folders are merged into one view: a folder of symbolic links, one per file, where the first folder that
holds a relative path wins. The view is built once per distinct set of files (its name is a hash of the
relative paths, the files they point to and their sizes and modification times), atomically, in samp's
cache, so concurrent processes (sweep members, dataset shards) share it.

A file of a user folder that takes the place of one further back is "shadowing": allowed (a user may
override a packaged dataset spec or experiment), and reported once per process by `conf_dir()`.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

__all__ = ["overlay", "visible_files"]

# Files of a config folder that never take part: editor leftovers, caches, hidden files.
_IGNORED_SUFFIXES = (".pyc", "~", ".swp")


def visible_files(folder: Path) -> dict[str, Path]:
    """Relative path (posix) -> file, for every regular file under `folder` (hidden ones and caches skipped)."""
    out = {}
    for root, dirs, files in os.walk(folder, followlinks=True):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "__pycache__")
        for name in sorted(files):
            if name.startswith(".") or name.endswith(_IGNORED_SUFFIXES):
                continue
            path = Path(root) / name
            out[path.relative_to(folder).as_posix()] = path
    return out


def overlay(folders: list[Path], cache: Path) -> tuple[Path, list[str]]:
    """The merged view of `folders` (first wins), kept under `cache`, and one line per shadowed config file.

    Returns (folder, shadowed): `folder` holds a link for every relative path found in any of `folders`;
    `shadowed` says, for each `.yaml` a later folder also has, which file is used and which is hidden."""
    chosen: dict[str, Path] = {}
    origin: dict[str, Path] = {}
    shadowed = []
    for folder in folders:
        for rel, path in visible_files(folder).items():
            if rel in chosen:
                if rel.endswith(".yaml"):
                    shadowed.append(f"{rel} of {origin[rel]} is used in place of the one in "
                                    f"{folder} (SAMP_CONFIG_PATH: the first folder that has a file wins)")
                continue
            chosen[rel], origin[rel] = path.resolve(), folder
    key = hashlib.sha256()
    for rel in sorted(chosen):
        stat = chosen[rel].stat()
        key.update(f"{rel}\0{chosen[rel]}\0{stat.st_size}\0{stat.st_mtime_ns}\n".encode())
    target = Path(cache) / key.hexdigest()[:16]
    if not target.is_dir():
        _build(target, chosen)
    return target, shadowed


def _build(target: Path, chosen: dict[str, Path]) -> None:
    """Write the links into a temporary sibling and rename it into place (another process may win the race;
    both views are the same, so the loser's is dropped)."""
    tmp = target.with_name(f".tmp-{target.name}-{os.getpid()}")
    shutil.rmtree(tmp, ignore_errors=True)
    for rel, path in chosen.items():
        link = tmp / rel
        link.parent.mkdir(parents=True, exist_ok=True)
        link.symlink_to(path)
    try:
        tmp.rename(target)
    except OSError:
        if not target.is_dir():
            raise
        shutil.rmtree(tmp, ignore_errors=True)
