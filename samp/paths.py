"""Where samp finds its configs and keeps its caches, and how it fingerprints files.

`SAMP_CONF_DIR`, `SAMP_CACHE_DIR` and `SAMP_RUNS_DIR` override the defaults (the repository's `conf/` and
`$XDG_CACHE_HOME/samp`, i.e. `~/.cache/samp`, and `runs/`).
"""

from __future__ import annotations

import hashlib
import os
from pathlib import Path

__all__ = ["REPO_ROOT", "cache_dir", "check_name", "conf_dir", "file_sha256", "find_checkpoint", "inside",
           "resolve_asset", "runs_root"]

REPO_ROOT = Path(__file__).resolve().parents[1]
PYBULLET_DATA_SCHEME = "pybullet_data://"


def conf_dir() -> Path:
    """The Hydra config root (`conf/` beside the package unless `SAMP_CONF_DIR` is set)."""
    path = Path(os.environ.get("SAMP_CONF_DIR", REPO_ROOT / "conf"))
    if not path.is_dir():
        raise FileNotFoundError(
            f"samp's config folder {path} does not exist. Install samp from a clone "
            "(`pip install -e .`) or point SAMP_CONF_DIR at a folder with samp's `conf/` layout."
        )
    return path


def runs_root() -> Path:
    """Where run folders go: `$SAMP_RUNS_DIR`, else `runs/` in the repository (one definition for every
    layer: the evaluation writes stand-alone results there too)."""
    return Path(os.environ.get("SAMP_RUNS_DIR", REPO_ROOT / "runs"))


def cache_dir(*parts: str) -> Path:
    """A folder under samp's disk cache, created if missing."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "samp"
    path = Path(os.environ.get("SAMP_CACHE_DIR", default)).joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def resolve_asset(ref: str, relative_to: Path | None = None) -> Path:
    """Resolve an asset reference: `pybullet_data://sub/path`, an absolute path, or a path relative
    to `relative_to` (the folder of the config that names it)."""
    if ref.startswith(PYBULLET_DATA_SCHEME):
        import pybullet_data

        path = Path(pybullet_data.getDataPath()) / ref[len(PYBULLET_DATA_SCHEME):]
    else:
        path = Path(ref).expanduser()
        if not path.is_absolute() and relative_to is not None:
            path = relative_to / path
    if not path.is_file():
        raise FileNotFoundError(f"asset {ref!r} resolves to {path}, which is not a file")
    return path.resolve()


def file_sha256(path) -> str:
    """Hex sha256 of a file's bytes, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def find_checkpoint(run_dir: str | Path) -> Path:
    """A run folder's policy checkpoint: `checkpoints/best.ckpt`, else `checkpoints/last.ckpt`;
    FileNotFoundError naming what is there."""
    from samp.names import CHECKPOINT_PREFERENCE, CHECKPOINTS_DIR

    folder = Path(run_dir) / CHECKPOINTS_DIR
    for name in CHECKPOINT_PREFERENCE:
        if (folder / name).is_file():
            return folder / name
    present = sorted(p.name for p in folder.glob("*")) if folder.is_dir() else []
    what = f"it holds {present}" if present else ("it is empty" if folder.is_dir() else "the folder does not exist")
    raise FileNotFoundError(f"no checkpoint to evaluate in {folder}: expected {' or '.join(CHECKPOINT_PREFERENCE)} "
                            f"({what}). Train the run to at least one checkpoint, or evaluate the expert with "
                            "planner=expert dataset=REF")


def check_name(name, what: str) -> str:
    """`name` if it is one plain folder name, else ValueError saying why. A name becomes a folder under a
    root (datasets, runs): a separator, `.`, `..`, an empty name or a leading dot (hidden, and the
    registry's own `.work` and `.tmp-*` folders) would put it elsewhere or hide it."""
    text = name if isinstance(name, str) else None
    problem = None
    if text is None:
        problem = f"it is a {type(name).__name__}, not a string"
    elif text.strip() == "":
        problem = "it is empty"
    elif text in (".", ".."):
        problem = "it names the folder itself or its parent"
    elif "/" in text or "\\" in text or os.sep in text or (os.altsep and os.altsep in text):
        problem = "it holds a path separator"
    elif "\0" in text:
        problem = "it holds a NUL character"
    elif text.startswith("."):
        problem = "it starts with '.' (a hidden folder)"
    if problem:
        raise ValueError(f"{what} {name!r} is not a plain folder name: {problem}. Use letters, digits, '_' and '-'")
    return text


def inside(root: Path, rel: str, what: str) -> Path:
    """`root / rel`, after checking that `rel` is relative and stays inside `root` (no `..`, no absolute
    path, no symlink out); ValueError naming `what` otherwise."""
    path = Path(rel)
    if path.is_absolute() or ".." in path.parts or rel in ("", "."):
        raise ValueError(f"{what}: {rel!r} must be a path inside {root} (relative, without '..')")
    full = root / path
    if not full.resolve().is_relative_to(root.resolve()):
        raise ValueError(f"{what}: {rel!r} leads outside {root} (to {full.resolve()})")
    return full
