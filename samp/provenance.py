"""Where a result came from: package version, git commit and dirty flag, library versions, host."""

from __future__ import annotations

import platform
import subprocess
from functools import lru_cache
from importlib import metadata

from samp import __version__
from samp.paths import REPO_ROOT, source_checkout

__all__ = ["code_version", "package_versions"]

TRACKED_PACKAGES = ("torch", "pytorch-lightning", "hydra-core", "pybullet", "pytorch-kinematics", "ompl",
                    "trimesh", "mcap", "rerun-sdk", "numpy")


def _git(*args: str) -> str | None:
    """git's answer about samp's own clone; None for an installed wheel (site-packages may sit inside some
    other project's repository, whose commit is not samp's)."""
    if not source_checkout():
        return None
    try:
        out = subprocess.run(["git", *args], cwd=REPO_ROOT, capture_output=True, text=True, timeout=10)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout.strip() if out.returncode == 0 else None


@lru_cache(maxsize=1)
def code_version() -> dict:
    """{"package": version, "git_commit": sha or None, "git_dirty": bool or None}."""
    commit = _git("rev-parse", "HEAD")
    status = _git("status", "--porcelain", "--untracked-files=no") if commit else None
    return {"package": __version__, "git_commit": commit, "git_dirty": None if status is None else bool(status)}


def package_versions() -> dict:
    versions = {"python": platform.python_version()}
    for name in TRACKED_PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions
