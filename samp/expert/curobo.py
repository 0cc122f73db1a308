"""Optional cuRobo backend (GPU trajectory optimisation, as the paper's expert) behind the planner interface.

Not implemented in this version: selecting it checks for cuRobo and CUDA and says what is missing, so a
config that asks for it fails at once with the install step instead of deep inside a run.
"""

from __future__ import annotations

__all__ = ["CuroboPlanner", "curobo_available"]

INSTALL = ("install cuRobo on a machine with a CUDA GPU: git clone https://github.com/NVlabs/curobo && "
           "cd curobo && pip install -e . --no-build-isolation (see https://curobo.org/get_started/1_install_instructions.html)")


def curobo_available() -> tuple[bool, str]:
    """(available, why not): cuRobo importable and a CUDA device present."""
    try:
        import curobo  # noqa: F401
    except ImportError:
        return False, f"the cuRobo backend needs the `curobo` package, which is not installed; {INSTALL}"
    import torch

    if not torch.cuda.is_available():
        return False, "the cuRobo backend needs a CUDA GPU, and torch sees none; use backend: ompl on this machine"
    return True, ""


class CuroboPlanner:
    """Same interface as `ExpertPlanner` (`plan(q_start, q_goal, seed) -> PlanResult`, context manager)."""

    backend = "curobo"

    def __init__(self, robot, scene, cfg):
        ok, why = curobo_available()
        if not ok:
            raise RuntimeError(why)
        raise NotImplementedError("the cuRobo backend is not implemented yet in samp.expert; use backend: ompl "
                                  "(the OMPL expert runs on any CPU)")

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return None

    def plan(self, q_start, q_goal, seed: int = 0):  # pragma: no cover - unreachable until implemented
        raise NotImplementedError
