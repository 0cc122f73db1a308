"""One config tree from several folders: the user's folders of `SAMP_CONFIG_PATH` in front of samp's own.

Hydra composes from one primary folder, and the rest of samp reads `conf_dir()/group/name.yaml` directly
(robots, scenes, expert settings, the help texts). So instead of teaching every reader a search path, the
folders are merged into one view: a folder of symbolic links, one per file, where the first folder that
holds a relative path wins. The view is built once per distinct set of files (its name is a hash of the
relative paths, the files they point to and their sizes and modification times), atomically, in samp's
cache, so concurrent processes (sweep members, dataset shards) share it.

A file of a user folder that takes the place of one further back is "shadowing": allowed (a user may
override a packaged dataset spec or experiment), and reported once per process by `conf_dir()`.

The user's folders are untrusted input, checked here, where they are read: the walk follows symbolic links
to folders (a user may link a shared `robot/` in) but refuses one that leads back to a folder the walk
already holds (`ln -s . again` would otherwise make the walk endless, or nest copies until the path is too
long), and every YAML file of theirs passes `samp.yaml_files.check_yaml` before the view is built, so a
broken or exploding file is named at the user's own path, not at its link in the cache.
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

__all__ = ["ConfigFolderError", "overlay", "visible_files"]

# Files of a config folder that never take part: editor leftovers, caches, hidden files.
_IGNORED_SUFFIXES = (".pyc", "~", ".swp")
_YAML_SUFFIXES = (".yaml", ".yml")
_checked: set[tuple[str, int, int]] = set()  # (file, size, mtime_ns) that passed check_yaml in this process


class ConfigFolderError(ValueError):
    """A config folder whose walk would not end, or would bring in one folder twice."""


def visible_files(folder: Path) -> dict[str, Path]:
    """Relative path (posix) -> file, for every regular file under `folder` (hidden ones and caches skipped).
    ConfigFolderError naming the link when a symbolic link leads to a folder the walk already holds (the
    folder itself, one above it, or one it reaches by another way)."""
    out = {}
    reached = {Path(folder).resolve(): Path(folder)}  # real folder -> the path under `folder` that reached it
    for root, dirs, files in os.walk(folder, followlinks=True):
        dirs[:] = sorted(d for d in dirs if not d.startswith(".") and d != "__pycache__")
        for d in dirs:
            _reach(Path(root) / d, reached, Path(folder))
        for name in sorted(files):
            if name.startswith(".") or name.endswith(_IGNORED_SUFFIXES):
                continue
            path = Path(root) / name
            out[path.relative_to(folder).as_posix()] = path
    return out


def _reach(sub: Path, reached: dict[Path, Path], folder: Path) -> None:
    """Note that the walk enters `sub`, refusing a second way into one real folder (checked before the walk
    enters it, so a loop costs one listing, not forty nested ones)."""
    real = sub.resolve()
    if real not in reached:
        reached[real] = sub
        return
    first = reached[real]
    link = sub if sub.is_symlink() or not first.is_symlink() else first
    other = first if link == sub else sub
    if sub.parent.resolve().is_relative_to(real):
        why = "a folder that holds the link itself, so the walk would never end; remove the link"
    else:  # two ways into one folder: each doubles what lies below, and chained they grow without bound
        why = f"a folder the walk already reaches as {other}; remove one of the two ways in"
    raise ConfigFolderError(f"config folder {folder} (SAMP_CONFIG_PATH): the symbolic link {link} leads to {real}, "
                            f"{why}")


def _check_yaml_files(files: dict[str, Path]) -> None:
    """Every YAML file of a user folder through `check_yaml` (once per process and version of the file)."""
    from samp.yaml_files import check_yaml

    for path in files.values():
        if not path.name.endswith(_YAML_SUFFIXES):
            continue
        real = path.resolve()
        stat = real.stat()
        key = (str(real), stat.st_size, stat.st_mtime_ns)
        if key not in _checked:
            check_yaml(path, "config file", mapping=True)
            _checked.add(key)


def overlay(folders: list[Path], cache: Path, trusted: tuple[Path, ...] = ()) -> tuple[Path, list[str]]:
    """The merged view of `folders` (first wins), kept under `cache`, and one line per shadowed config file.
    The YAML files of every folder but the `trusted` ones (samp's own) are checked first (`check_yaml`).

    Returns (folder, shadowed): `folder` holds a link for every relative path found in any of `folders`;
    `shadowed` says, for each `.yaml` a later folder also has, which file is used and which is hidden."""
    chosen: dict[str, Path] = {}
    origin: dict[str, Path] = {}
    shadowed = []
    for folder in folders:
        files = visible_files(folder)
        if folder not in trusted:
            _check_yaml_files(files)
        for rel, path in files.items():
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
