"""Distributed (DDP) launches: which process owns the run folder, and how the others find it.

Lightning starts one process per extra DDP rank with the parent's environment, so rank 0 puts its run
folder in `RUN_DIR_ENV` and the other ranks attach to that folder instead of making new ones.
"""

from __future__ import annotations

import os

__all__ = ["RUN_DIR_ENV", "is_rank_zero"]

# Set by the rank-0 process of `samp.train` to its run folder, so that the processes Lightning starts for
# the other DDP ranks (they inherit the environment) attach to the same folder instead of making new ones.
RUN_DIR_ENV = "SAMP_RUN_DIR"


def is_rank_zero() -> bool:
    """True in the process that owns the run folder (global rank 0, or no distributed launch at all)."""
    for var in ("RANK", "SLURM_PROCID", "LOCAL_RANK"):  # Lightning's order of precedence
        if os.environ.get(var) not in (None, ""):
            return int(os.environ[var]) == 0
    return True
