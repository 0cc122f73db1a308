"""Process lifetime of generation's helpers, kept free of heavy imports: the spawned manager process unpickles
`die_with_parent` by importing this module, which then costs it no torch, pybullet or OMPL start-up."""

from __future__ import annotations

import os
import signal
import sys

__all__ = ["die_with_parent"]


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
