"""The merge lock without flock (`samp.data.merging.merge_lock`: an exclusive lock file, created atomically,
that records its holder), with real processes: two contending processes never hold it together, and of two
waiters on a stale lock only one takes it over; a stale lock (its process gone, its pid reused, another
host's lock not refreshed) is taken over with one warning line; a live one is waited for, and given up with
the holder named; a merge killed half-way (SIGKILL while assembling the dataset, after publishing it, or
while removing the work folder) is recovered by the next merge: the same dataset id, nothing temporary left.
"""

from __future__ import annotations

import json
import os
import platform
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from samp.data import generate, load_spec, merge
from samp.data.generation import work_dir
from samp.data.merging import MERGING, TRASH
from samp.data.merging import LOCK_NAME, STALE_AFTER_S, MergeLockTimeout, merge_lock

DEADLINE = 120  # seconds; a bound on a poll, never a timing that is asserted

# A process that takes the lock `rounds` times (once every process of the test has started) and logs
# "in PID" / "out PID" around each hold, so that any overlap of two holders shows in the log.
CONTENDER = """
import os, sys, time
from pathlib import Path
import samp.data.merging as merging
merging.POLL_S = 0.01
work, log, go, rounds = Path(sys.argv[1]), Path(sys.argv[2]), Path(sys.argv[3]), int(sys.argv[4])
print("ready", flush=True)
while not go.exists():
    time.sleep(0.01)
for _ in range(rounds):
    with merging.merge_lock(work, "contended"):
        holder = (work / merging.LOCK_NAME).read_text()
        with open(log, "a") as f:
            f.write(f"in {os.getpid()} {holder}")
        time.sleep(0.05)
        with open(log, "a") as f:
            f.write(f"out {os.getpid()}\\n")
"""

# A process that takes the lock, says so and holds it until it is killed.
HOLDER = """
import sys, time
from pathlib import Path
from samp.data.merging import merge_lock
with merge_lock(Path(sys.argv[1]), "held"):
    print("held", flush=True)
    time.sleep(600)
"""


def _env() -> dict:
    return {**os.environ, "OMP_NUM_THREADS": "1"}


def _holder(work: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(work)], stdout=subprocess.PIPE, text=True, env=_env())
    assert proc.stdout.readline().strip() == "held"
    return proc


def _killed_holder(work: Path) -> int:
    """The pid of a process that took the lock and was killed (SIGKILL) holding it: its lock file stays."""
    proc = _holder(work)
    proc.kill()
    proc.wait()
    assert (work / LOCK_NAME).is_file()
    return proc.pid


def _contend(work: Path, log: Path, processes: int = 2, rounds: int = 5) -> list[subprocess.CompletedProcess]:
    go = work.parent / "go"
    procs = [subprocess.Popen([sys.executable, "-c", CONTENDER, str(work), str(log), str(go), str(rounds)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
             for _ in range(processes)]
    for p in procs:
        assert p.stdout.readline().strip() == "ready"
    go.touch()  # all at once
    done = []
    for p in procs:
        out, err = p.communicate(timeout=DEADLINE)
        assert p.returncode == 0, err
        done.append(subprocess.CompletedProcess(p.args, p.returncode, out, err))
    return done


def _check_exclusive(log: Path, pids: set[int], rounds: int) -> None:
    """Every hold in the log ends before the next begins, and each process held the lock `rounds` times,
    its own lock file (host, pid, start time) in place while it did."""
    lines = log.read_text().splitlines()
    assert len(lines) == 2 * rounds * len(pids), lines
    for enter, leave in zip(lines[::2], lines[1::2]):
        _, pid, record = enter.split(" ", 2)
        assert leave == f"out {pid}", f"another process took the lock while {pid} held it:\n" + "\n".join(lines)
        holder = json.loads(record)
        assert holder["pid"] == int(pid) and holder["host"] == platform.node() and holder["started"] > 0
    assert {int(line.split()[1]) for line in lines} == pids


def test_two_processes_never_hold_the_lock_together(tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    done = _contend(work, tmp_path / "log")
    _check_exclusive(tmp_path / "log", _pids(tmp_path / "log"), 5)
    assert sum(out.stdout.count("is merging") for out in done) >= 1, "neither process ever waited for the other"
    assert not any("taking over" in out.stderr for out in done), [out.stderr for out in done]
    assert sorted(p.name for p in work.iterdir()) == [], "a lock file or a temporary file was left behind"


def _pids(log: Path) -> set[int]:
    pids = {int(line.split()[1]) for line in log.read_text().splitlines()}
    assert len(pids) == 2, pids
    return pids


def test_a_stale_lock_is_taken_over_by_one_of_two_waiters(tmp_path):
    work = tmp_path / "work"
    work.mkdir()
    dead = _killed_holder(work)
    done = _contend(work, tmp_path / "log")
    _check_exclusive(tmp_path / "log", _pids(tmp_path / "log"), 5)
    warnings = [line for out in done for line in out.stderr.splitlines() if "taking over" in line]
    assert len(warnings) == 1, "\n".join(out.stderr for out in done)
    assert warnings[0].startswith("warning: contended: taking over the merge lock ") and f"process {dead} on " in \
        warnings[0] and warnings[0].endswith(": that process is gone"), warnings[0]
    assert sorted(p.name for p in work.iterdir()) == []


def test_the_lock_of_a_killed_process_is_taken_over_with_a_warning(tmp_path, capfd):
    work = tmp_path / "work"
    work.mkdir()
    dead = _killed_holder(work)
    with merge_lock(work, "mine", timeout=DEADLINE):
        mine = json.loads((work / LOCK_NAME).read_text())
        assert mine["pid"] == os.getpid()
    assert not (work / LOCK_NAME).exists()
    out, err = capfd.readouterr()
    assert out == "" and len(err.splitlines()) == 1 and f"taking over the merge lock {work / LOCK_NAME} of process " \
        f"{dead} on {platform.node()} since " in err, err


@pytest.mark.parametrize("kind", ["legacy", "reused pid", "other host, old"])
def test_other_stale_locks_are_taken_over(tmp_path, capfd, kind):
    """A lock of the flock version (`process PID on HOST`, its process gone), one whose pid now runs a
    process started after the lock, and one of another host not refreshed for longer than STALE_AFTER_S."""
    work = tmp_path / "work"
    work.mkdir()
    lock = work / LOCK_NAME
    other = None
    if kind == "legacy":
        gone = subprocess.Popen([sys.executable, "-c", "pass"])
        gone.wait()
        lock.write_text(f"process {gone.pid} on {platform.node()}\n")
        reason = "that process is gone"
    elif kind == "reused pid":
        other = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(600)"])
        lock.write_text(json.dumps({"host": platform.node(), "pid": other.pid, "started": time.time() - 60}))
        reason = "its process id now belongs to a younger process"
    else:
        lock.write_text(json.dumps({"host": "elsewhere.invalid", "pid": 4242, "started": time.time() - 7200}))
        old = time.time() - STALE_AFTER_S - 60
        os.utime(lock, (old, old))
        reason = "its lock file was last refreshed"
    try:
        with merge_lock(work, "mine", timeout=DEADLINE):
            assert json.loads(lock.read_text())["pid"] == os.getpid()
    finally:
        if other is not None:
            other.kill()
            other.wait()
    err = capfd.readouterr().err
    assert len(err.splitlines()) == 1 and "taking over the merge lock" in err and reason in err, err


@pytest.mark.parametrize("kind", ["live process", "other host, fresh"])
def test_a_live_lock_is_waited_for_and_the_timeout_names_its_holder(tmp_path, capfd, kind):
    work = tmp_path / "work"
    work.mkdir()
    holder = None
    if kind == "live process":
        holder = _holder(work)
        who = f"process {holder.pid} on {platform.node()} since "
    else:
        (work / LOCK_NAME).write_text(json.dumps({"host": "elsewhere.invalid", "pid": 4242, "started": time.time(),
                                                  "started_utc": "2026-01-01T00:00:00+00:00"}))
        who = "process 4242 on elsewhere.invalid since 2026-01-01T00:00:00+00:00"
    try:
        with pytest.raises(MergeLockTimeout, match=r"waited 1 s for the merge lock .*; " + re.escape(who)
                           + r".* still holds it \(its lock file was refreshed \d+ s ago\)\. If that process is gone, "
                           r"delete .*merge\.lock and merge again"):
            with merge_lock(work, "waiting", timeout=1):
                pytest.fail("the lock was taken while its holder lives")
    finally:
        if holder is not None:
            holder.kill()
            holder.wait()
    out = capfd.readouterr().out
    assert out.startswith(f"waiting: {who}") and out.rstrip().endswith(f"is merging {work}; waiting for it to finish")


def test_a_work_folder_removed_while_waiting_ends_the_wait(tmp_path):
    """The holder merged and removed the work folder (with its lock file): the waiter's block runs without a
    lock, and the caller finds the work folder gone."""
    work = tmp_path / "work"
    work.mkdir()
    code = ("import shutil, sys, time\nfrom pathlib import Path\nfrom samp.data.merging import merge_lock\n"
            "work = Path(sys.argv[1])\nwith merge_lock(work, 'held'):\n    print('held', flush=True)\n"
            "    time.sleep(1)\n    shutil.rmtree(work)\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(work)], stdout=subprocess.PIPE, text=True, env=_env())
    assert proc.stdout.readline().strip() == "held"
    with merge_lock(work, "waiting", timeout=DEADLINE):
        assert not work.exists()
    assert proc.wait(timeout=DEADLINE) == 0


# ----------------------------------------------------------------------------- a merge killed half-way
SPEC = {"name": "killed", "robot": "panda", "seed": 7, "train_scenes": 2, "val_scenes": 1, "test_scenes": 0,
        "trajectories_per_scene": 1, "eval_problems_per_scene": 1, "generators": ["tabletop"], "resolutions": [8],
        "detour_share": 0.0}

# Run in the merging process: SIGKILL itself at a point of the merge (argv[2]), as a kill from outside would.
KILLED_MERGE = """
import json, os, signal, sys
from pathlib import Path
import samp.data.generation as generation

point, root = sys.argv[2], Path(sys.argv[3])

def die():
    os.kill(os.getpid(), signal.SIGKILL)

if point == "assembling":  # after the first scene file is in the dataset's temporary folder
    link = generation.link_or_copy
    def link_or_copy(src, dst):
        link(src, dst)
        die()
    generation.link_or_copy = link_or_copy
elif point == "published":  # the dataset renamed into place, the work folder not yet removed
    finalize = generation.finalize_dataset
    def finalize_dataset(*args, **kwargs):
        finalize(*args, **kwargs)
        die()
    generation.finalize_dataset = finalize_dataset
elif point == "removing":  # the work folder renamed aside, not yet deleted
    remove, calls = generation.remove_trash, []
    def remove_trash(folder):
        calls.append(folder)
        if len(calls) == 2:  # the first is merge's own clean-up before it starts
            die()
        remove(folder)
    generation.remove_trash = remove_trash
generation.merge(json.loads(sys.argv[1]), root)
"""


@pytest.fixture(scope="module")
def scenes(tmp_path_factory):
    """A work folder holding every scene of SPEC (two shards, not merged), and the id a clean merge gives."""
    root = tmp_path_factory.mktemp("killed_scenes")
    assert generate(SPEC, shard=0, num_shards=2, root=root, progress=False) is None
    from samp.data.generation import run_scene

    spec = load_spec(SPEC)
    work = work_dir(spec, root)
    resolved = spec.resolved()
    for job in spec.scene_jobs():
        if not (work / job.file).is_file():
            run_scene({k: resolved[k] for k in type(spec).__dataclass_fields__ if k in resolved}, job, str(work))
    clean = tmp_path_factory.mktemp("clean_merge")
    shutil.copytree(root / SPEC["name"], clean / SPEC["name"])
    return root / SPEC["name"], merge(SPEC, clean).name


def _leftovers(root: Path) -> list[str]:
    """What a merge leaves in the dataset's folder besides the datasets: work, temporary and lock files."""
    return sorted(str(p.relative_to(root)) for p in (root / SPEC["name"]).rglob("*")
                  if any(part.startswith(".") for part in p.relative_to(root / SPEC["name"]).parts))


@pytest.mark.slow
@pytest.mark.parametrize("point", ["assembling", "published", "removing"])
def test_a_merge_killed_half_way_is_recovered_by_the_next(scenes, tmp_path, capfd, point):
    folder, ident = scenes
    shutil.copytree(folder, tmp_path / SPEC["name"])
    work = work_dir(load_spec(SPEC), tmp_path)
    killed = subprocess.Popen([sys.executable, "-c", KILLED_MERGE, json.dumps(SPEC), point, str(tmp_path)],
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())
    _, stderr = killed.communicate(timeout=300)
    assert killed.returncode == -signal.SIGKILL, stderr[-2000:]
    datasets = sorted(p.name for p in (tmp_path / SPEC["name"]).iterdir() if not p.name.startswith("."))
    # what the kill left: the state the next merge must recover from
    if point == "assembling":
        assert datasets == [] and (work / LOCK_NAME).is_file() and len(list(work.glob(MERGING + "*"))) == 1
    elif point == "published":
        assert datasets == [ident] and (work / LOCK_NAME).is_file() and not list(work.glob(MERGING + "*"))
    else:
        assert datasets == [ident] and not work.exists() and len(list(work.parent.glob(TRASH + "*"))) == 1
    capfd.readouterr()
    dest = merge(SPEC, tmp_path)
    assert dest == tmp_path / SPEC["name"] / ident, f"the recovered merge gave {dest.name}, a clean merge {ident}"
    assert sorted(p.name for p in (tmp_path / SPEC["name"]).iterdir()) == [ident]
    assert _leftovers(tmp_path) == [], "the recovered merge left a work, temporary or lock file behind"
    out, err = capfd.readouterr()
    if point == "removing":
        assert f"already merged into {SPEC['name']}@{ident}" in out and err == "", err
    else:
        assert len(err.splitlines()) == 1 and f"taking over the merge lock {work / LOCK_NAME} of process " \
            f"{killed.pid} on " in err and err.rstrip().endswith(": that process is gone"), err
