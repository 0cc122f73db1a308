"""Where a result came from: package version, git commit and dirty flag, library versions, host."""

from __future__ import annotations

import os
import platform
import subprocess
from functools import lru_cache
from importlib import metadata
from pathlib import Path

from samp import __version__
from samp.paths import REPO_ROOT, source_checkout

__all__ = ["code_version", "package_versions", "process_gone"]

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


def process_gone(pid: int, started: float | None = None) -> str | None:
    """Why process `pid` of this host is gone (or is not the process that started at `started`, a Unix time,
    any more: its id reused by a younger process), or None while it may be running. A lock's holder and a
    run's trainer are judged by it."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return "that process is gone"
    except PermissionError:  # alive, another user's
        pass
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:  # gone meanwhile, or no /proc: taken as alive until the next look
        return None
    fields = stat[stat.rindex(")") + 2:].split()
    if fields[0] in ("Z", "X"):
        return "that process is gone (a zombie)"
    if started is not None:
        born = _boot_time() + int(fields[19]) / os.sysconf("SC_CLK_TCK")
        if born > started + 2.0:  # the clock-tick start time of /proc is good to a second
            return "that process is gone (its process id now belongs to a younger process)"
    return None


_BOOT: list[float] = []


def _boot_time() -> float:
    if not _BOOT:
        lines = Path("/proc/stat").read_text().splitlines()
        _BOOT.append(float(next(line.split()[1] for line in lines if line.startswith("btime "))))
    return _BOOT[0]
