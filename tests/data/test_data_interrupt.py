"""Interruption without residue (issue 21), with real processes and signals: Ctrl-C stops a generation at
once (one line, exit 130, finished scenes kept, workers gone); workers die with a SIGKILLed parent; a
merge lock left by a killed merge is taken over and a live one is waited for; merging is never a
silent success without a dataset."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import psutil
import pytest

from samp.data import GenerationError, generate, load_spec, merge
from samp.data.generation import work_dir

pytestmark = pytest.mark.slow  # subprocess CLIs, training or dataset generation: deselected by `make test-fast`

SPEC = {"name": "halted", "robot": "panda", "seed": 5, "train_scenes": 4, "val_scenes": 0, "test_scenes": 0,
        "trajectories_per_scene": 4, "eval_problems_per_scene": 0, "generators": ["tabletop"], "resolutions": [8], "detour_share": 0.0}
OVERRIDES = ["+dataset=quickstart", "dataset.name=halted", "dataset.seed=5", "dataset.train_scenes=4",
             "dataset.val_scenes=0", "dataset.test_scenes=0", "dataset.trajectories_per_scene=4",
             "dataset.eval_problems_per_scene=0", "dataset.generators=[tabletop]", "dataset.resolutions=[8]",
             "dataset.detour_share=0"]  # SPEC's (quickstart asks for detours)
DEADLINE = 180  # seconds; generous: only a bound on a poll, never a timing that is asserted


def _until(condition, what: str, proc=None):
    deadline = time.monotonic() + DEADLINE
    while not condition():
        assert proc is None or proc.poll() is None, f"the process ended before {what}"
        assert time.monotonic() < deadline, f"no {what} after {DEADLINE} s"
        time.sleep(0.05)


# A `sitecustomize` for the generation's processes: each worker runs its first scene as usual and then waits
# before any further one, so when the test interrupts, at least one scene is finished and at least two are
# not, however fast generation is. Watching for a file and then signalling was a race: on a fast machine
# every scene could be done before the signal arrived.
HOLD_AFTER_FIRST_SCENE = """
import functools, os, time
import samp.data.generation as generation

_run_scene, _done = generation.run_scene, []


@functools.wraps(_run_scene)
def run_scene(*args, **kwargs):
    if _done:  # this process finished a scene already: hold until the test has interrupted the generation
        time.sleep(60)
    _done.append(os.getpid())
    return _run_scene(*args, **kwargs)


generation.run_scene = run_scene
"""


def _start(root, *extra, hold: Path | None = None) -> subprocess.Popen:
    """`python -m samp.data generate` of SPEC; with `hold` (a folder holding HOLD_AFTER_FIRST_SCENE as its
    sitecustomize.py) every process of it holds after its first scene."""
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    if hold is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(hold), *filter(None, [env.get("PYTHONPATH")])])
    # SIGINT at its default, as a terminal's foreground command has it: a suite started as a background job of
    # a non-interactive shell runs with SIGINT ignored, which the CLI would inherit and the signal would not stop.
    return subprocess.Popen([sys.executable, "-m", "samp.data", "generate", *OVERRIDES, f"root={root}", "progress=false",
                             "workers=2", *extra], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
                            preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_DFL))


def _workers(proc) -> list[psutil.Process]:
    """The generation's worker processes (python children running the pool), not the manager."""
    try:
        children = psutil.Process(proc.pid).children(recursive=True)
    except psutil.NoSuchProcess:
        return []
    return [c for c in children if "spawn_main" in " ".join(c.cmdline())]


def _gone(processes) -> bool:
    return not any(p.is_running() and p.status() != psutil.STATUS_ZOMBIE for p in processes)


def test_ctrl_c_stops_at_once_keeps_finished_scenes_and_exits_130(tmp_path):
    work = work_dir(load_spec({**load_spec("quickstart").__dict__, **SPEC}), tmp_path)
    hold = tmp_path / "hold"
    hold.mkdir()
    (hold / "sitecustomize.py").write_text(HOLD_AFTER_FIRST_SCENE)
    proc = _start(tmp_path, hold=hold)
    _until(lambda: len(_workers(proc)) >= 2 and any(work.glob("scene_*.mcap")), "finished scene", proc)
    workers = [psutil.Process(p.pid) for p in _workers(proc)]
    proc.send_signal(signal.SIGINT)  # to the parent only, as `kill -INT`; a terminal would signal the group
    out, err = proc.communicate(timeout=DEADLINE)
    assert proc.returncode == 130, err[-2000:]
    # pybullet prints its build time when a worker imports it; everything else is samp's
    lines = [line for line in err.splitlines() if line.strip() and not line.startswith("pybullet build time")]
    assert len(lines) == 1 and "interrupted;" in lines[0] and "finished and kept in" in lines[0], err
    assert "Traceback" not in err
    _until(lambda: _gone(workers), "end of the workers")
    kept = sorted(p.name for p in work.glob("scene_*.mcap"))
    assert 1 <= len(kept) < 4 and f"{len(kept)} of 4 scenes" in lines[0], (kept, lines[0])
    again = _start(tmp_path)
    out, err = again.communicate(timeout=600)
    assert again.returncode == 0, err[-2000:]
    assert f"resuming, {len(kept)} of 4 scenes already done" in out


def test_workers_die_with_a_killed_parent(tmp_path):
    proc = _start(tmp_path)
    _until(lambda: len(_workers(proc)) >= 2, "worker processes", proc)
    family = [psutil.Process(p.pid) for p in psutil.Process(proc.pid).children(recursive=True)]  # workers, manager
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    _until(lambda: _gone(family), "end of the orphaned workers")


@pytest.fixture
def scenes_done(tmp_path):
    """Every scene of SPEC generated in shards (shard 0 of 2, then shard 1's scenes without merging)."""
    assert generate(SPEC, shard=0, num_shards=2, root=tmp_path, progress=False) is None
    from samp.data.generation import run_scene

    spec = load_spec(SPEC)
    work = work_dir(spec, tmp_path)
    resolved = spec.resolved()
    for job in spec.scene_jobs():
        if not (work / job.file).is_file():
            run_scene({k: resolved[k] for k in type(spec).__dataclass_fields__ if k in resolved}, job, str(work))
    return work


# A process that takes the merge lock of the work folder argv[1], says so and holds it until it is killed.
HOLD_THE_MERGE_LOCK = ("import sys, time\nfrom pathlib import Path\nfrom samp.data.merging import merge_lock\n"
                       "with merge_lock(Path(sys.argv[1]), 'halted'):\n    print('held', flush=True)\n    time.sleep(600)\n")


def _lock_holder(work: Path) -> subprocess.Popen:
    holder = subprocess.Popen([sys.executable, "-c", HOLD_THE_MERGE_LOCK, str(work)], stdout=subprocess.PIPE, text=True)
    assert holder.stdout.readline().strip() == "held"
    return holder


def test_a_lock_left_by_a_killed_merge_is_taken_over(scenes_done, tmp_path, capfd):
    holder = _lock_holder(scenes_done)
    holder.kill()  # SIGKILL: its lock file stays, as a killed merge leaves it
    holder.wait()
    assert (scenes_done / "merge.lock").is_file()
    dest = merge(SPEC, tmp_path)
    assert (dest / "manifest.json").is_file() and not scenes_done.exists()
    assert f"taking over the merge lock {scenes_done / 'merge.lock'} of process {holder.pid} " in capfd.readouterr().err


def test_a_live_merge_is_waited_for_and_its_dataset_returned(scenes_done, tmp_path):
    """A process holding the lock makes `merge` wait; once it is gone the merge completes. A second merge
    of a merged spec returns the dataset instead of failing or succeeding without one."""
    holder = _lock_holder(scenes_done)
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    merging = subprocess.Popen([sys.executable, "-m", "samp.data", "merge", *OVERRIDES, f"root={tmp_path}"],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    first = merging.stdout.readline()
    assert "is merging" in first and "waiting for it to finish" in first, first
    assert merging.poll() is None
    holder.kill()
    holder.wait()
    out, err = merging.communicate(timeout=DEADLINE)
    assert merging.returncode == 0, err
    assert "dataset halted@" in out
    again = merge(SPEC, tmp_path)
    assert (again / "manifest.json").is_file()


def test_nothing_to_merge_is_an_error(tmp_path):
    with pytest.raises(GenerationError, match=r"cannot merge 'halted': 4 of 4 scenes are not generated yet"):
        merge(SPEC, tmp_path)


def test_a_worker_ends_without_teardown_but_with_its_output_flushed():
    """`exit_without_teardown` (a generation worker's last exit handler): the interpreter's teardown is skipped
    (an exit handler registered before it, as torch's are, does not run), what the worker printed is still
    flushed, and the exit status is 0."""
    code = ("import atexit, sys; atexit.register(lambda: sys.stdout.write('teardown ran')); "
            "from samp.data.lifecycle import exit_without_teardown; exit_without_teardown(); "
            "sys.stdout.write('scene written'); sys.stderr.write('a warning')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert (out.returncode, out.stdout, out.stderr) == (0, "scene written", "a warning")
