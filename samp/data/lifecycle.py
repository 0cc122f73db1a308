"""Process set-up of generation's helpers, kept free of heavy imports: the spawned manager process unpickles
`die_with_parent` by importing this module, which then costs it no torch, pybullet or OMPL start-up.

`reproducible_mkl`: the IK's small linear solves go through torch's MKL, which picks its kernels by CPU
(AVX2, AVX-512, ...) and rounds differently with each; a last-bit difference sends OMPL down another path
and gives the dataset another id. A process that plans asks MKL for its CPU-independent path first. MKL
fixes its path at its first call, and that path is 2 to 5 times slower for training's large products, so a
training process is never switched (docs/datasets.md, "The same bytes on every CPU")."""

from __future__ import annotations

import atexit
import os
import queue
import signal
import sys

__all__ = ["REPRODUCIBLE_MKL", "die_with_parent", "drain", "end_workers", "exit_without_teardown", "reproducible_mkl"]

# Intel MKL's conditional numerical reproducibility: the same results on every x86 CPU.
REPRODUCIBLE_MKL = {"MKL_CBWR": "COMPATIBLE"}


def reproducible_mkl() -> None:
    """Ask MKL for its CPU-independent results unless the environment sets them; effective only before the
    process's first MKL call."""
    for key, value in REPRODUCIBLE_MKL.items():
        os.environ.setdefault(key, value)


def die_with_parent(parent: int) -> None:
    """In a worker (or the manager) process: die when the generating process dies, even by SIGKILL, and
    leave Ctrl-C to it (a terminal sends SIGINT to the whole group; the parent ends the workers itself)."""
    if sys.platform.startswith("linux"):
        import ctypes

        PR_SET_PDEATHSIG = 1
        ctypes.CDLL(None, use_errno=True).prctl(PR_SET_PDEATHSIG, signal.SIGKILL)
    if os.getppid() != parent:  # the parent died before the line above: nobody is left to serve
        os._exit(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def exit_without_teardown() -> None:
    """In a worker process: end it, when its work is done, without the interpreter's teardown of torch, OMPL
    and the rest (~1 s per spawned process, which the generating process waits for at shutdown). Runs
    first among the exit handlers (registered last); the worker has written its scene files and sent its
    results, and an exit status of a pool worker is not read."""
    def leave() -> None:
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (AttributeError, OSError, ValueError):
                pass
        os._exit(0)

    atexit.register(leave)


def end_workers(pool) -> None:
    """Cancel what is queued and end the running workers now (a scene half planned is lost, as after a kill)."""
    processes = list(getattr(pool, "_processes", {}).values())  # the executor keeps its workers here
    pool.shutdown(wait=False, cancel_futures=True)
    for p in processes:
        p.kill()
    for p in processes:
        p.join(timeout=30)


def drain(ticks, bar) -> None:
    """Move the finished-problem ticks the workers queued onto the progress bar."""
    while True:
        try:
            bar.update(ticks.get_nowait())
        except queue.Empty:
            return
