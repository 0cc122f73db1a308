"""Evaluation problems: start and goal pairs in a scene, with the expert's answer kept for comparison.

`problems_from_dataset(ds, split, count, seed)` takes the evaluation problems a dataset stores for the
scenes of one split ("train", "val" or "test"): problems sampled and planned by the expert like the
demonstrations, but from a seed stream of their own and stored apart from them, so no policy trained on
the dataset has seen them; the expert's solution and planning time come with each (or the reason it
failed). "train" therefore measures new problems in seen scenes, "val" the scenes that chose the
checkpoint, "test" scenes seen by nothing before (docs/design.md section 4). The choice is fixed by `seed`:
problems are spread as evenly as possible over the split's scenes (a seeded draw within each scene),
then ordered by scene and problem, so a rollout batch visits one scene after another.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from samp.cli import paste
from samp.eval.names import SPLITS
from samp.names import SPLIT_ALIASES

__all__ = ["GridSource", "Problem", "dataset_grids", "problems_from_dataset", "scene_grids"]

GridSource = Callable[["Problem", int], torch.Tensor]  # (problem, n_e) -> (n_e, n_e, n_e) anchor grid


def _config(q, name: str) -> np.ndarray:
    if isinstance(q, torch.Tensor):
        q = q.detach().cpu().double().numpy()
    q = np.array(q, dtype=np.float64)
    if q.ndim != 1 or not np.all(np.isfinite(q)):
        raise ValueError(f"{name} must be a finite (n,) configuration in radians, got shape {q.shape}")
    return q


@dataclass
class Problem:
    """One planning problem (radians, robot base frame).

    Args:
        scene: the `Scene`.
        q_start: (n,) the start configuration.
        q_goal: (n,) the goal configuration; the goal pose is the end-effector pose there.
        split: "train" | "val" | "test" for dataset problems; metrics are reported per split.
        name: where it came from (dataset, scene, problem), for records and recordings.
        scene_index: the scene's index in its dataset (None for a free-standing problem).
        robot: the robot name the problem was made for (checked against the planner's robot), or None.
        expert_trajectory: (W, n) the expert's solution, or None (not planned, or the expert failed).
        expert_time: the expert's planning time in seconds, or None.
        expert_reason: why the expert failed on this problem (None when it solved it or never tried).
        scene_hash: the scene's identity, `Scene.content_hash()` (filled in from the scene when not given).
    """

    scene: object
    q_start: np.ndarray
    q_goal: np.ndarray
    split: str = "all"
    name: str = ""
    scene_index: int | None = None
    robot: str | None = None
    expert_trajectory: np.ndarray | None = field(default=None, repr=False)
    expert_time: float | None = None
    expert_reason: str | None = None
    scene_hash: str | None = None

    def __post_init__(self):
        self.q_start, self.q_goal = _config(self.q_start, "q_start"), _config(self.q_goal, "q_goal")
        if self.scene_hash is None and hasattr(self.scene, "content_hash"):
            self.scene_hash = self.scene.content_hash()
        if self.q_start.shape != self.q_goal.shape:
            raise ValueError(f"q_start and q_goal must have the same length, got {self.q_start.shape} and {self.q_goal.shape}")
        if self.expert_trajectory is not None:
            traj = np.asarray(self.expert_trajectory, dtype=np.float64)
            if traj.ndim != 2 or traj.shape[1] != len(self.q_start):
                raise ValueError(f"expert_trajectory must be (W, {len(self.q_start)}), got {traj.shape}")
            self.expert_trajectory = traj


def _spread(available: list[int], count: int, rng: np.random.Generator) -> list[int]:
    """How many of `count` problems each scene gets: as even as possible, capped by what it has."""
    take = [0] * len(available)
    left = count
    order = list(rng.permutation(len(available)))  # who gets the remainder is seeded too
    while left > 0:
        room = [i for i in order if take[i] < available[i]]
        if not room:
            break
        for i in room[:left]:
            take[i] += 1
            left -= 1
    return take


def problems_from_dataset(ds, split: str, count: int | None = None, seed: int = 0,
                          detour_only: bool = False) -> list[Problem]:
    """Up to `count` (None: all) of the evaluation problems the dataset stores for its `split` scenes
    ("train" | "val" | "test"; "heldout", the older name, reads as "val"), with the expert's
    solution and planning time, or its failure reason in `expert_reason`. Problems for which no valid goal
    was found are left out (there is nothing to plan); with `detour_only`, so are those whose straight line
    from start to goal was not found blocked when they were drawn (their stored `detour` is not true).

    Raises ValueError when the dataset predates stored evaluation problems, has no scenes in that split,
    or no problems in them.
    """
    if split not in SPLITS and split not in SPLIT_ALIASES:
        raise ValueError(f"split must be one of {SPLITS} (or the older 'heldout', read as 'val'), got {split!r}")
    split = SPLIT_ALIASES.get(split, split)
    if count is not None and count < 1:
        raise ValueError(f"problems must be a positive count (or null for all), got {count}")
    label = f"dataset {ds.name}@{ds.id}"
    if not ds.has_eval_problems:
        raise ValueError(f"{label} predates stored evaluation problems (its problems would be its own training "
                         f"demonstrations); regenerate it with `{paste('python -m samp.data generate', dataset=ds.name)}`")
    scenes = ds.scene_indices(split)
    if not scenes:
        counts = {s: ds.scene_split.count(s) for s in SPLITS}
        others = [s for s in SPLITS if s != split and counts[s]]
        raise ValueError(f"{label} has no {split} scenes (scenes per split: {counts}); evaluate "
                         f"{'splits=[' + ','.join(others) + ']' if others else 'another dataset'}, or generate a "
                         f"dataset with {split}_scenes > 0")
    stored = {i: [p for p in ds.eval_problems if p["scene"] == i and p["goal"] is not None
                  and (p.get("detour") is True or not detour_only)] for i in scenes}
    available = [len(stored[i]) for i in scenes]
    if sum(available) == 0:
        raise ValueError(f"{label} has {split} scenes but no evaluation problems with a valid goal in them; generate "
                         "a dataset with eval_problems_per_scene > 0")
    rng = np.random.default_rng(seed)
    take = _spread(available, sum(available) if count is None else count, rng)
    robot = ds.manifest.get("robot", {}).get("name")
    problems = []
    for i, k in zip(scenes, take):
        for j in sorted(rng.choice(len(stored[i]), size=k, replace=False).tolist()):
            p = stored[i][j]
            problems.append(Problem(ds.scenes[i], p["start"], p["goal"], split=split, scene_index=i, robot=robot,
                                    name=f"{ds.name}@{ds.id}/scene{i}/problem{p['index']}",
                                    expert_trajectory=p["solution"], expert_time=p["planning_time"],
                                    expert_reason=None if p["success"] else p["reason"],
                                    scene_hash=ds.scene_hashes[i]))
    return problems


def scene_grids(problem: Problem, n_e: int) -> torch.Tensor:
    """(n_e, n_e, n_e) anchor grid of the problem's scene over its bounds, computed (and disk-cached)."""
    return problem.scene.anchor_grid(n_e)


def dataset_grids(ds) -> GridSource:
    """A grid source that decodes the dataset's stored grids where it has the resolution, and computes
    the scene's exact grid otherwise (the same values: both are `scene.anchor_grid`)."""

    def source(problem: Problem, n_e: int) -> torch.Tensor:
        if problem.scene_index is not None and n_e in ds.resolutions:
            return ds.grid(problem.scene_index, n_e)
        return scene_grids(problem, n_e)

    return source
