"""Where samp finds its configs, where it writes, and how it fingerprints files.

Configs: samp's own (`conf/` in a clone, `samp/_conf/` in an installed wheel; `SAMP_CONF_DIR` replaces
them), with the folders of `SAMP_CONFIG_PATH` (`dir1:dir2`, the user's own `robot/`, `scene/`, `dataset/`,
`experiment/` ...) in front: `conf_dir()` is then a merged view of all of them (docs/design.md section 2).

Output: runs and datasets go under the project folder (`project_dir`: `$SAMP_HOME`, else the clone when
samp runs from one, else the current folder; never site-packages) unless `SAMP_RUNS_DIR` and
`SAMP_DATASETS_DIR` say otherwise; the cache is `$SAMP_CACHE_DIR`, else `$XDG_CACHE_HOME/samp`, i.e.
`~/.cache/samp`.
"""

from __future__ import annotations

import hashlib
import os
import sys
import time
from pathlib import Path

__all__ = ["REPO_ROOT", "cache_dir", "check_name", "conf_dir", "config_path", "env_folder", "file_sha256", "find_checkpoint",
           "inside", "packaged_conf_dir", "project_dir", "resolve_asset", "runs_root", "shown_path", "source_checkout",
           "user_config", "unique_tmp", "write_cache_file"]

REPO_ROOT = Path(__file__).resolve().parents[1]
PACKAGED_CONF = Path(__file__).resolve().parent / "_conf"  # where a wheel carries conf/ (see setup.py)
PYBULLET_DATA_SCHEME = "pybullet_data://"
_said: set[str] = set()


def source_checkout() -> bool:
    """True when samp runs from a clone of its repository (an editable install or the clone on sys.path),
    False for an installed wheel."""
    return not PACKAGED_CONF.is_dir() and (REPO_ROOT / "conf").is_dir() and (REPO_ROOT / "pyproject.toml").is_file()


def project_dir() -> Path:
    """The folder whose `runs/` and `datasets/` samp uses by default: `$SAMP_HOME`, else the clone when samp
    runs from one, else the current folder."""
    if os.environ.get("SAMP_HOME"):
        home = Path(os.environ["SAMP_HOME"]).expanduser()
        if home.exists() and not home.is_dir():
            raise NotADirectoryError(f"SAMP_HOME={home} is a file, not a folder. Point SAMP_HOME at a folder "
                                     "(it is created when missing)")
        home.mkdir(parents=True, exist_ok=True)
        return home
    return REPO_ROOT if source_checkout() else Path.cwd()


def packaged_conf_dir() -> Path:
    """samp's own config tree: `$SAMP_CONF_DIR`, else the wheel's `samp/_conf/`, else the clone's `conf/`."""
    if os.environ.get("SAMP_CONF_DIR"):
        path = Path(os.environ["SAMP_CONF_DIR"]).expanduser()
    else:
        path = PACKAGED_CONF if PACKAGED_CONF.is_dir() else REPO_ROOT / "conf"
    if not path.is_dir():
        raise FileNotFoundError(
            f"samp's config folder {path} does not exist. Reinstall samp (`pip install samp-*.whl` or "
            "`pip install -e .` in a clone), or point SAMP_CONF_DIR at a folder with samp's `conf/` layout.")
    return path


def config_path() -> list[Path]:
    """The user's config folders of `$SAMP_CONFIG_PATH` (`os.pathsep`-separated), in order; each must exist."""
    folders = []
    for entry in os.environ.get("SAMP_CONFIG_PATH", "").split(os.pathsep):
        if not entry.strip():
            continue
        path = Path(entry).expanduser().resolve()
        if not path.is_dir():
            raise FileNotFoundError(f"SAMP_CONFIG_PATH names {entry!r}, which is not a folder. Create it or "
                                    "remove it from SAMP_CONFIG_PATH")
        folders.append(path)
    return folders


def conf_dir() -> Path:
    """The Hydra config root: samp's own configs, or, with `SAMP_CONFIG_PATH` set, a merged view in which
    the user's folders come first (their `group/name.yaml` shadow samp's, which is said once)."""
    own, user = packaged_conf_dir(), config_path()
    if not user:
        return own
    from samp.config_overlay import overlay

    folder, shadowed = overlay([*user, own], cache_dir("config"), trusted=(own,))  # the user's files are checked
    for line in shadowed:
        if line not in _said:
            _said.add(line)
            print(f"samp: {line}", file=sys.stderr)
    return folder


def shown_path(path: Path) -> Path:
    """The file to name in a message about `path`: a config of the merged view (`conf_dir()`) that comes from
    a user's folder is named at the user's own file, which they can open and fix, not at its link in samp's
    cache; any other path is kept as it is."""
    return Path(path).resolve() if user_config(path) else Path(path)


def user_config(path: Path) -> Path | None:
    """The `SAMP_CONFIG_PATH` folder a config file of `conf_dir()` comes from, None for samp's own."""
    real = Path(path).resolve()
    return next((folder for folder in config_path() if real.is_relative_to(folder)), None)


def env_folder(variable: str, default) -> Path:
    """The folder `$variable` names (else `default`, a path or a function giving one, called only then);
    ValueError when a file stands there, so that the user reads which variable to fix rather than a
    NotADirectoryError from deep inside a command."""
    path = Path(os.environ.get(variable) or (default() if callable(default) else default)).expanduser()
    if path.exists() and not path.is_dir():
        where = f"{variable}={os.environ[variable]}" if os.environ.get(variable) else f"the default folder {path}"
        raise ValueError(f"{where} is a file, not a folder; point {variable} at a folder (it is created when missing)"
                         + ("" if os.environ.get(variable) else " or move the file away"))
    return path


def runs_root() -> Path:
    """Where run folders go: `$SAMP_RUNS_DIR`, else `runs/` in the project folder (one definition for every
    layer: the evaluation writes stand-alone results there too)."""
    return env_folder("SAMP_RUNS_DIR", lambda: project_dir() / "runs")


def cache_dir(*parts: str) -> Path:
    """A folder under samp's disk cache, created if missing."""
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "samp"
    path = env_folder("SAMP_CACHE_DIR", default).joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def unique_tmp(path: Path) -> Path:
    """A temporary name beside `path` that no other process uses (a file several processes write)."""
    return path.with_name(f"{path.name}.{os.getpid()}-{time.time_ns()}.tmp")


def write_cache_file(path: Path, write) -> None:
    """Write one cache entry atomically: `write(f)` fills a binary file under a `unique_tmp` name, which then
    replaces `path`. Workers that build the same entry at once (the robot's points in each generation worker)
    each put identical bytes in place; none loses its temporary to another."""
    tmp = unique_tmp(path)
    try:
        with open(tmp, "wb") as f:
            write(f)
        tmp.replace(path)
    finally:
        tmp.unlink(missing_ok=True)


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
