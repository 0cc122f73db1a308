"""What merging scene files into a dataset needs besides the scenes themselves: the merge lock, moving
files into the new dataset, and the manifest's summary of the scenes' sidecars (`samp.data.generation`)."""

from __future__ import annotations

import os
import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from samp.names import SPLIT_ALIASES, SPLITS

__all__ = ["EVAL_PREFIX", "build_manifest", "link_or_copy", "merge_lock"]

EVAL_PREFIX = "eval_"  # the evaluation problems' times in a sidecar: eval_planning_time, ...


@contextmanager
def merge_lock(work: Path, name: str):
    """An exclusive lock on `work/merge.lock` (fcntl.flock), held for the block. The kernel releases it when
    its holder dies, however it dies, so a lock file left by a killed merge is simply taken over; a live
    holder is waited for."""
    import fcntl
    import platform

    lock = work / "merge.lock"
    fd = os.open(lock, os.O_CREAT | os.O_RDWR)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            owner = os.pread(fd, 200, 0).decode(errors="replace").strip() or "another process"
            print(f"{name}: {owner} is merging {work}; waiting for it to finish", flush=True)
            fcntl.flock(fd, fcntl.LOCK_EX)
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"process {os.getpid()} on {platform.node()}\n".encode(), 0)
        yield
    finally:
        os.close(fd)  # releases the lock


def link_or_copy(src: Path, dst: Path) -> None:
    """A hard link of `src` at `dst`, or a copy where the file system refuses one."""
    try:
        os.link(src, dst)
    except OSError:
        shutil.copy2(src, dst)


def build_manifest(config: dict, config_hash: str, seed: int, asset_hash: str, sidecars: list[dict],
                   parents: list[str]) -> dict:
    """Everything a manifest records besides the file list, id, name, format version and time.

    `scenes` lists every scene's sidecar: index, name, file, split, generator and seed, content hash,
    counts of demonstrations (episodes, trajectories) and evaluation problems (eval_problems, eval_solved),
    and the wall-clock planner times of both."""
    scenes = sorted(sidecars, key=lambda s: s["scene_index"])
    # A rewritten legacy dataset's sidecars may say "heldout": it counts as "val".
    split = {s: [x["name"] for x in scenes if SPLIT_ALIASES.get(x["split"], x["split"]) == s] for s in SPLITS}
    counts = {"scenes": len(scenes), **{f"{s}_scenes": len(split[s]) for s in SPLITS},
              "episodes": sum(s["episodes"] for s in scenes), "trajectories": sum(s["trajectories"] for s in scenes),
              "eval_problems": sum(s.get("eval_problems", 0) for s in scenes),
              "eval_solved": sum(s.get("eval_solved", 0) for s in scenes)}
    counts["failures"] = counts["episodes"] - counts["trajectories"]
    # problems whose straight joint-space line is blocked (the expert plans a detour); older sidecars lack them
    counts.update(detours=sum(s.get("detours", 0) for s in scenes), eval_detours=sum(s.get("eval_detours", 0) for s in scenes))
    counts["eval_failures"] = counts["eval_problems"] - counts["eval_solved"]
    return {"config": config, "config_hash": config_hash, "seed": seed,
            "robot": {"name": config["robot"], "asset_hash": asset_hash}, "parents": parents, "counts": counts,
            "splits": split, "scenes": scenes, "planning_time": _time_summary(scenes, "planning_time"),
            "eval_planning_time": _time_summary(scenes, EVAL_PREFIX + "planning_time")}


def _time_summary(scenes: list[dict], key: str) -> dict:
    times = [t for s in scenes for t in s.get(key, [])]
    return {"total_s": float(np.sum(times)) if times else 0.0, "mean_s": float(np.mean(times)) if times else 0.0}
