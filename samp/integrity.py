"""Loading what a user points at without running its code, and checking it is what a run recorded.

`torch.load(weights_only=False)` unpickles arbitrary objects, so a crafted checkpoint runs code when it is
loaded. `load_torch_file` loads with `weights_only=True`: tensors, containers and plain values, plus the
few classes in `SAFE_GLOBALS`. A file that needs anything else is refused, naming the classes it asks for
and the opt-in: `trust=True` (`load_policy(..., trust_checkpoint=True)`, `trust_checkpoint=true` on the
command lines) or `SAMP_TRUST_CHECKPOINTS=1`, for files from someone you trust (checkpoints written by
older samp versions, say).

A run folder records the sha256 of its checkpoints and artifacts in `run.json` (`files_sha256`) when the
run ends; `check_recorded_hash` compares a file against that record before it is loaded, so a flipped byte
is an error naming the file instead of different trajectories.
"""

from __future__ import annotations

import json
import os
import pickle
import warnings
from pathlib import Path

from samp.names import CHECKPOINTS_DIR, RUN_JSON
from samp.paths import file_sha256

__all__ = ["FILES_SHA256", "TRUST_ENV", "IntegrityError", "check_recorded_hash", "hash_run_files", "load_torch_file",
           "run_of", "safe_globals", "trusted"]

TRUST_ENV = "SAMP_TRUST_CHECKPOINTS"
FILES_SHA256 = "files_sha256"  # run.json: {path relative to the run folder: sha256}
HASHED = (f"{CHECKPOINTS_DIR}/*.ckpt", "*.pt")  # what a run's record covers


class IntegrityError(ValueError):
    """A file that is not what its record says, or that would run code when loaded."""


def safe_globals() -> list:
    """Classes a samp checkpoint may hold beyond what `weights_only=True` allows by default: the config
    containers Hydra may hand to `save_hyperparameters` and the paths Lightning's callbacks keep. None of
    them runs code when rebuilt."""
    import pathlib

    out: list = [pathlib.PosixPath, pathlib.WindowsPath, pathlib.PurePosixPath, pathlib.PureWindowsPath]
    try:
        from omegaconf import DictConfig, ListConfig
        from omegaconf.base import ContainerMetadata, Metadata
        from omegaconf.nodes import AnyNode, BooleanNode, FloatNode, IntegerNode, StringNode

        out += [DictConfig, ListConfig, ContainerMetadata, Metadata, AnyNode, BooleanNode, FloatNode, IntegerNode,
                StringNode]
    except ImportError:  # omegaconf is a dependency; without it there is nothing of it to allow
        pass
    try:
        from lightning_fabric.utilities.data import AttributeDict

        out.append(AttributeDict)
    except ImportError:
        pass
    return out


def trusted(trust: bool | None = None) -> bool:
    """The opt-in to full unpickling: `trust`, else the environment variable SAMP_TRUST_CHECKPOINTS=1."""
    if trust is not None:
        return bool(trust)
    return os.environ.get(TRUST_ENV, "").strip().lower() in ("1", "true", "yes")


def load_torch_file(path: str | Path, what: str = "checkpoint", trust: bool | None = None, map_location="cpu",
                    **kwargs):
    """`torch.load` of a file a user pointed at, without running code from it (module docstring).

    Raises FileNotFoundError for a missing file and IntegrityError naming the file for one that asks for
    other classes (with the opt-in) or that is not a readable torch file (truncated, damaged)."""
    import torch

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no {what} at {path}")
    if trusted(trust):
        warnings.warn(f"loading {path} with full unpickling (trusted): it can run code", stacklevel=2)
        return _load(torch, path, what, dict(map_location=map_location, weights_only=False, **kwargs))
    with torch.serialization.safe_globals(safe_globals()):
        return _load(torch, path, what, dict(map_location=map_location, weights_only=True, **kwargs))


def _load(torch, path: Path, what: str, kwargs: dict):
    try:
        return torch.load(path, **kwargs)
    except pickle.UnpicklingError as err:
        if not kwargs["weights_only"]:
            raise IntegrityError(f"{path} is not a readable {what} ({err}); restore it or train again") from None
        try:
            asks = ", ".join(torch.serialization.get_unsafe_globals_in_checkpoint(path)) or "unknown"
        except Exception:  # noqa: BLE001 - the list is a hint; the refusal stands either way
            asks = "unknown"
        raise IntegrityError(
            f"{path} was refused: loading it would rebuild objects outside samp's allow-list ({asks}), and "
            f"unpickling them can run code. If you trust whoever wrote the file (e.g. a checkpoint from an older "
            f"samp), load it with trust_checkpoint=true (load_policy(..., trust_checkpoint=True)) or "
            f"{TRUST_ENV}=1") from None
    except (RuntimeError, EOFError, OSError, ValueError, KeyError) as err:
        raise IntegrityError(f"{path} is not a readable {what}: {type(err).__name__}: {str(err).splitlines()[0].rstrip('.')}. It "
                             "is truncated or damaged; restore it, or train the run again") from None


def run_of(path: Path) -> Path | None:
    """The run folder holding `path` (its folder, or the one above `checkpoints/`), if it has a run.json."""
    for folder in (path.parent, path.parent.parent):
        if (folder / RUN_JSON).is_file():
            return folder
    return None


def hash_run_files(run_dir: str | Path) -> dict[str, str]:
    """{path relative to the run folder: sha256} of its checkpoints and artifacts."""
    run_dir = Path(run_dir)
    files = sorted({p for pattern in HASHED for p in run_dir.glob(pattern) if p.is_file()})
    return {p.relative_to(run_dir).as_posix(): file_sha256(p) for p in files}


def check_recorded_hash(path: str | Path) -> str | None:
    """Compare `path` with the sha256 its run recorded when it ended; IntegrityError naming the file,
    expected and actual on a mismatch. Returns the recorded hash, or None when there is no record to
    compare with (not in a run folder, an older run, or a run still running, whose checkpoints change)."""
    path = Path(path)
    run = run_of(path)
    if run is None:
        return None
    try:
        record = json.loads((run / RUN_JSON).read_text())
    except (json.JSONDecodeError, UnicodeDecodeError, OSError):
        return None  # the run registry reports a damaged record; the file itself is checked on loading
    if not isinstance(record, dict) or record.get("status") == "running":
        return None
    rel = path.resolve().relative_to(run.resolve()).as_posix()
    expected = (record.get(FILES_SHA256) or {}).get(rel)
    if expected is None:
        return None
    actual = file_sha256(path)
    if actual != expected:
        raise IntegrityError(f"{path} is not the file its run recorded: sha256 expected {expected} ({run / RUN_JSON}, "
                             f"{FILES_SHA256}), actual {actual}. It was changed or damaged after the run ended; restore "
                             "it from a copy, or train the run again")
    return expected
