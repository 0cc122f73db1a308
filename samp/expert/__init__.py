"""Expert demonstrations: start/goal sampling with batched IK, the OMPL planner, trajectory post-processing.
Names are imported on first use: the expert's config needs no torch or OMPL."""

from samp import lazy_exports

__getattr__, __all__ = lazy_exports(__name__, {
    **{name: "samp.expert.config" for name in ("ExpertConfig", "IKConfig", "ProblemConfig", "available_expert_configs",
                                               "load_expert_config")},
    "IKResult": "samp.expert.ik", "solve_ik": "samp.expert.ik", "available_planners": "samp.expert.ompl_backend",
    **{name: "samp.expert.planner" for name in ("ExpertPlanner", "PlanResult", "make_planner", "plan_scene")},
    "derive_seed": "samp.expert.seeding",
    "PlanningProblem": "samp.expert.problems", "sample_problems": "samp.expert.problems",
    **{name: "samp.expert.trajectory" for name in ("ee_path_length", "first_invalid_segment", "joint_path_length",
                                                   "resample")}})
