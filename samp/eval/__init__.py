"""Rollout evaluation: problems from a dataset, batched policy rollouts checked in pybullet, the paper's
metrics for the policy and the expert on the same problems, and Rerun recordings.

    from samp.eval import Problem, load_planner, evaluate, problems_from_dataset
    problems = problems_from_dataset(open_dataset("standard"), "test", count=100, seed=0)  # or "train", "val"
    result = evaluate(load_planner("runs/EXP/TIME"), problems)   # or load_planner("expert")
    result["metrics"]["test"]["success_rate"]

Names are imported on first use, so `python -m samp.eval` fails fast on a bad config.
"""

from importlib import import_module

_EXPORTS = {
    "EvalConfig": "config", "RolloutConfig": "config", "load_eval_config": "config", "rollout_config": "config",
    "EXPERT_VARIANTS": "planners", "EnvBatch": "planners", "ExpertTrajectoryPlanner": "planners", "PlannedTrajectory": "planners",
    "StepPolicy": "planners", "StraightLinePolicy": "planners", "TrajectoryPlanner": "planners",
    "clamp_to_limits": "planners",
    "Problem": "problems", "dataset_grids": "problems", "problems_from_dataset": "problems", "scene_grids": "problems",
    "TrajectoryChecker": "checks", "goal_errors": "checks", "polyline_length": "checks",
    "RolloutResult": "rollouts", "rollout": "rollouts",
    "markdown_table": "metrics", "summarize": "metrics",
    "evaluate": "harness",
    "find_checkpoint": "loading", "load_planner": "loading", "read_run": "loading",
    "EvalCallback": "callback",
    "write_recording": "recording",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    if name not in _EXPORTS:
        raise AttributeError(f"module 'samp.eval' has no attribute {name!r}")
    value = getattr(import_module(f"samp.eval.{_EXPORTS[name]}"), name)
    globals()[name] = value
    return value
