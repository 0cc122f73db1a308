"""What merging scene files into a dataset needs besides the scenes themselves: the merge lock, moving
files into the new dataset, and the manifest's summary of the scenes' sidecars (`samp.data.generation`).

The merge lock (`merge_lock`) is a lock file, `<work folder>/merge.lock`, that only one process can create:
a file written in full under a unique name and hard-linked to `merge.lock` (`os.link` fails when the name
exists; where a file system has no hard links, `os.open(O_CREAT | O_EXCL)`). It records its holder's host,
process id and start time, and works wherever the work folder is shared (NFS, Lustre mounted without flock),
which `fcntl.flock` does not. A lock outlives a holder that dies without releasing it (SIGKILL, a lost node),
so a waiting merge judges the holder and takes a stale lock over with a one-line warning:
  * a holder on this host is alive while its process id runs a process started no later than the lock;
    once that process is gone (or a zombie, or the id belongs to a younger process) the lock is stale;
  * a holder on another host cannot be asked: it touches the lock file every `HEARTBEAT_S` (30 s), and its
    lock is stale once the file's time is more than `STALE_AFTER_S` (10 minutes) old, by the waiter's clock
    (the hosts' clocks must agree within minutes, as NTP keeps them). A lock file that cannot be read (a
    holder killed while writing it through the O_EXCL fallback) is judged by its age the same way.
A live holder is waited for (one line says who holds it) for at most `WAIT_TIMEOUT_S` (6 h), after which
`MergeLockTimeout` names the holder. Two waiters never both take one stale lock over: the take-over itself
is done under a second lock file (`merge.lock.break`), after checking that the stale lock is unchanged.
"""

from __future__ import annotations

import errno
import json
import os
import platform
import re
import shutil
import sys
import threading
import time
import uuid
from contextlib import contextmanager
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from samp.names import SPLIT_ALIASES, SPLITS
from samp.provenance import process_gone

__all__ = ["EVAL_PREFIX", "HEARTBEAT_S", "MERGING", "STALE_AFTER_S", "TRASH", "WAIT_TIMEOUT_S", "MergeLockTimeout",
           "build_manifest", "held", "link_or_copy", "lock_content", "merge_lock", "move_aside", "remove_trash"]

EVAL_PREFIX = "eval_"  # the evaluation problems' times in a sidecar: eval_planning_time, ...

LOCK_NAME = "merge.lock"
HEARTBEAT_S = 30.0  # a holder touches its lock file this often
STALE_AFTER_S = 600.0  # a lock of another host (or unreadable) whose file is older than this is stale
WAIT_TIMEOUT_S = 6 * 3600.0  # how long a merge waits for a live holder before it gives up
BREAK_STALE_S = 60.0  # a take-over lock (merge.lock.break) older than this was left by a killed take-over
POLL_S = 0.5


class MergeLockTimeout(TimeoutError):
    """A merge waited `timeout` seconds for a live holder of the merge lock; the message names the holder."""


@contextmanager
def merge_lock(work: Path, name: str, timeout: float = WAIT_TIMEOUT_S):
    """An exclusive lock on the work folder `work` (module docstring), held for the block. A live holder is
    waited for, a stale one taken over. When `work` disappears while waiting (the holder merged it and
    removed it), the block runs without a lock: the caller finds the dataset made."""
    lock = work / LOCK_NAME
    content = _acquire(lock, name, timeout)
    if content is None:
        yield
        return
    with held(lock, content):
        yield


@contextmanager
def held(lock: Path, content: bytes):
    """Keep the lock file `lock` (created holding `content`) refreshed for the block, then remove it if it
    is still ours."""
    stop = threading.Event()
    beat = threading.Thread(target=_heartbeat, args=(lock, content, stop), name="merge-lock-heartbeat", daemon=True)
    beat.start()
    try:
        yield
    finally:
        stop.set()
        beat.join()
        try:
            if lock.read_bytes() == content:  # still ours (the merge may have moved the work folder away)
                lock.unlink()
        except FileNotFoundError:
            pass


_HOST = platform.node()
_LEGACY = re.compile(rb"process (\d+) on (\S+)")  # what the flock lock of earlier versions wrote


def lock_content() -> bytes:
    now = time.time()
    return (json.dumps({"host": _HOST, "pid": os.getpid(), "started": now,
                        "started_utc": datetime.fromtimestamp(now, timezone.utc).isoformat(timespec="seconds"),
                        "token": uuid.uuid4().hex}) + "\n").encode()


def _acquire(lock: Path, name: str, timeout: float) -> bytes | None:
    """The content of `lock` once it is ours; None when its folder is gone (the holder we waited for merged)."""
    deadline = time.monotonic() + timeout
    announced = None
    while True:
        if not lock.parent.is_dir():
            return None
        content = lock_content()  # its start time: now
        try:
            if _create(lock, content):
                return content
        except FileNotFoundError:  # the folder went away meanwhile
            continue
        seen = _read(lock)
        if seen is None:  # released meanwhile
            continue
        raw, holder, age = seen
        reason = _stale(holder, age)
        if reason is not None:
            _take_over(lock, raw, content, f"{name}: taking over the merge lock {lock} of {_describe(holder)}: {reason}")
            continue
        if raw != announced:
            print(f"{name}: {_describe(holder)} is merging {lock.parent}; waiting for it to finish", flush=True)
            announced = raw
        if time.monotonic() > deadline:
            raise MergeLockTimeout(
                f"{name}: waited {timeout:.0f} s for the merge lock {lock}; {_describe(holder)} still holds it "
                f"(its lock file was refreshed {age:.0f} s ago). If that process is gone, delete {lock} and merge again")
        time.sleep(POLL_S)


def _create(lock: Path, content: bytes) -> bool:
    """Create `lock` holding `content`, atomically: True when this call made it, False when it exists."""
    tmp = lock.with_name(f".{lock.name}.{re.sub(r'[^A-Za-z0-9.-]', '_', _HOST)}.{os.getpid()}.{uuid.uuid4().hex[:12]}")
    tmp.write_bytes(content)
    try:
        try:
            os.link(tmp, lock)
            return True
        except OSError as err:
            if os.stat(tmp).st_nlink == 2:  # NFS: the link was made though its reply was lost
                return True
            if isinstance(err, FileExistsError):
                return False
            if err.errno not in (errno.EPERM, errno.ENOTSUP, errno.EOPNOTSUPP, errno.ENOSYS, errno.EMLINK):
                raise
        try:  # a file system without hard links: exclusive creation (NFSv3 and later honour O_EXCL)
            fd = os.open(lock, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            return False
        try:
            os.write(fd, content)
            os.fsync(fd)
        finally:
            os.close(fd)
        return True
    finally:
        tmp.unlink(missing_ok=True)


def _read(lock: Path) -> tuple[bytes, dict, float] | None:
    """(the lock file's bytes, its holder, seconds since it was last written or touched), or None without one."""
    try:
        raw = lock.read_bytes()
        age = time.time() - lock.stat().st_mtime
    except FileNotFoundError:
        return None
    try:
        holder = json.loads(raw)
        holder = holder if isinstance(holder, dict) else {}
    except (json.JSONDecodeError, UnicodeDecodeError):
        legacy = _LEGACY.search(raw)
        holder = {"pid": int(legacy[1]), "host": legacy[2].decode(errors="replace")} if legacy else {}
    return raw, holder, age


def _describe(holder: dict) -> str:
    if not isinstance(holder.get("pid"), int):
        return "an unknown process (an unreadable lock file)"
    since = f" since {holder['started_utc']}" if holder.get("started_utc") else ""
    return f"process {holder['pid']} on {holder.get('host') or 'an unknown host'}{since}"


def _stale(holder: dict, age: float) -> str | None:
    """Why the lock of `holder` (its file `age` seconds old) is stale, or None while its holder may be alive."""
    pid = holder.get("pid")
    if holder.get("host") == _HOST and isinstance(pid, int):
        started = holder.get("started")
        return process_gone(pid, started if isinstance(started, (int, float)) else None)
    if age > STALE_AFTER_S:
        return f"its lock file was last refreshed {age:.0f} s ago (stale after {STALE_AFTER_S:.0f} s)"
    return None


def _take_over(lock: Path, stale: bytes, content: bytes, warning: str) -> None:
    """Remove the stale lock file `lock` (holding `stale`) under the take-over lock, so that of several
    waiters exactly one removes it, and only while it is the file judged stale."""
    breaker = lock.with_name(lock.name + ".break")
    try:
        made = _create(breaker, content)
    except FileNotFoundError:
        return
    if not made:  # another waiter is taking over, or one was killed doing so (it takes milliseconds)
        try:
            if time.time() - breaker.stat().st_mtime > BREAK_STALE_S:
                breaker.unlink()
        except FileNotFoundError:
            pass
        time.sleep(POLL_S)
        return
    try:
        if lock.read_bytes() == stale:
            lock.unlink()
            print(f"warning: {warning}", file=sys.stderr, flush=True)
    except FileNotFoundError:
        pass
    finally:
        breaker.unlink(missing_ok=True)


def _heartbeat(lock: Path, content: bytes, stop: threading.Event) -> None:
    """Touch the lock file every HEARTBEAT_S while it is ours: a holder on another host is alive while it does."""
    while not stop.wait(HEARTBEAT_S):
        try:
            if lock.read_bytes() != content:
                return
            os.utime(lock)
        except OSError:
            return


MERGING = ".merging-"  # the dataset being assembled, in the work folder: <work>/.merging-<pid>-<ns>/
TRASH = ".removed-"  # a merged work folder being removed: <root>/<name>/.work/.removed-<hash16>-<pid>-<ns>/


def move_aside(work: Path) -> None:
    """Rename a merged work folder aside, in one step, before it is removed: a merge killed while removing
    leaves no work folder with scenes missing (which the next merge would take for unfinished shards),
    only a `.removed-*` folder. The merge lock goes with it: waiters find the work folder gone."""
    try:
        work.rename(work.parent / f"{TRASH}{work.name}-{os.getpid()}-{time.time_ns()}")
    except OSError:
        shutil.rmtree(work, ignore_errors=True)


def remove_trash(work_parent: Path) -> None:
    """Remove the `.removed-*` folders of `<root>/<name>/.work/` (merged work folders), and that folder when
    it is left empty."""
    if not work_parent.is_dir():
        return
    for trash in work_parent.glob(TRASH + "*"):
        shutil.rmtree(trash, ignore_errors=True)
    try:
        work_parent.rmdir()  # only when empty
    except OSError:
        pass


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
