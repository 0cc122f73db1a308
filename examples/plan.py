"""Plan one problem in a scene the policy never saw: `python examples/plan.py RUN_DIR [SEED]`."""

import sys

import torch

from samp.expert import sample_problems
from samp.policy import load_policy
from samp.robot import load_robot
from samp.scene import generate_scene

policy = load_policy(sys.argv[1], device="auto")  # a run folder of `python -m samp.train`
scene = generate_scene("shelf", seed=int(sys.argv[2]) if len(sys.argv) > 2 else 7)
exact = load_robot(policy.robot.name, dtype=torch.float64)  # the expert's problem sampler plans in float64
problem = next(p for p in sample_problems(exact, scene, 10, seed=0) if p.q_goal is not None)
result = policy.plan(scene, problem.q_start, problem.q_goal)
print(f"{result.termination} after {result.steps} steps: {result.trajectory.shape} trajectory, "
      f"goal error {100 * result.position_error:.1f} cm / {result.orientation_error:.1f} deg, "
      f"{1e3 * result.solution_time:.0f} ms ({1e3 * result.setup_time:.1f} ms for the scene)")
