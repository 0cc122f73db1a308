"""Planned work, not offered: a cuRobo backend (GPU trajectory optimisation, as the paper's expert).

Selecting `backend: curobo` is refused by `samp.expert.config.load_expert_config` with `NOT_IMPLEMENTED`. The
interface it would implement is the OMPL expert's (`samp.expert.planner.ExpertPlanner`):

  * `CuroboPlanner(robot, scene, cfg)`: a context manager owning cuRobo's world model of `scene`'s obstacles
    (cuboids, meshes) and its robot model from the robot's URDF and collision spheres;
  * `plan(q_start, q_goal, seed) -> PlanResult`: a `MotionGen` plan from q_start to q_goal (joint-space goal),
    resampled to `cfg.waypoints` and checked densely on `samp.sim.World` with `cfg.check_margin` like the OMPL
    expert's, so both backends' trajectories pass the same check; failures come back with their reason.

It needs cuRobo (https://curobo.org) and a CUDA GPU; `curobo_available` says what is missing on this machine.
"""

from __future__ import annotations

__all__ = ["CuroboPlanner", "NOT_IMPLEMENTED", "curobo_available"]

NOT_IMPLEMENTED = ("is not implemented: a cuRobo backend is planned work (samp/expert/curobo.py describes its "
                   "interface); use backend: ompl, the OMPL expert, which runs on any CPU")
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
        return False, "the cuRobo backend needs a CUDA GPU, and torch sees none"
    return True, ""


class CuroboPlanner:
    """The planned interface (see the module docstring); constructing it raises NotImplementedError."""

    backend = "curobo"

    def __init__(self, robot, scene, cfg):
        raise NotImplementedError(f"the cuRobo backend {NOT_IMPLEMENTED}")
