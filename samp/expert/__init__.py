"""Expert demonstrations: start/goal sampling with batched IK, the OMPL planner, trajectory post-processing."""

from samp.expert.config import ExpertConfig, IKConfig, ProblemConfig, available_expert_configs, load_expert_config
from samp.expert.ik import IKResult, solve_ik
from samp.expert.ompl_backend import available_planners
from samp.expert.planner import ExpertPlanner, PlanResult, derive_seed, make_planner, plan_scene
from samp.expert.problems import PlanningProblem, sample_problems
from samp.expert.trajectory import ee_path_length, first_invalid_segment, joint_path_length, resample

__all__ = ["ExpertConfig", "ExpertPlanner", "IKConfig", "IKResult", "PlanResult", "PlanningProblem", "ProblemConfig",
           "available_expert_configs", "available_planners", "derive_seed", "ee_path_length", "first_invalid_segment",
           "joint_path_length", "load_expert_config", "make_planner", "plan_scene", "resample", "sample_problems",
           "solve_ik"]
