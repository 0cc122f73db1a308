"""Evaluation problems: start and goal pairs in a scene, with the expert's answer kept for comparison.

`problems_from_dataset(ds, split, count, seed)` takes the problems of one scene split of a dataset:
the start and goal of expert trajectories in the training scenes ("train") or in the held-out scenes
("heldout"), so the expert's own trajectory and planning time come with each problem. The choice is
fixed by `seed`: problems are spread as evenly as possible over the split's scenes (a seeded draw within
each scene), then ordered by scene and episode, so a rollout batch visits one scene after another.

Note: every trajectory of a training scene may have been seen in training; the held-out split is the
generalisation test (DESIGN section 4 reports the two separately).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch

from samp.eval.names import SPLITS

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
        q_start, q_goal: (n,) configurations; the goal pose is the end-effector pose at q_goal.
        split: "train" | "heldout" for dataset problems; metrics are reported per split.
        name: where it came from (dataset, scene, episode), for records and recordings.
        scene_index: the scene's index in its dataset (None for a free-standing problem).
        robot: the robot name the problem was made for (checked against the planner's robot), or None.
        expert_trajectory: (W, n) the expert's solution, or None.
        expert_time: the expert's planning time in seconds, or None.
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

    def __post_init__(self):
        self.q_start, self.q_goal = _config(self.q_start, "q_start"), _config(self.q_goal, "q_goal")
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


def problems_from_dataset(ds, split: str, count: int | None = None, seed: int = 0) -> list[Problem]:
    """Up to `count` problems (None: all) from the expert trajectories of the dataset's `split` scenes.

    Raises ValueError when the dataset has no scenes (or no solved trajectories) in that split.
    """
    if split not in SPLITS:
        raise ValueError(f"split must be one of {SPLITS}, got {split!r}")
    if count is not None and count < 1:
        raise ValueError(f"problems must be a positive count (or null for all), got {count}")
    scenes = ds.scene_indices(split)
    label = f"dataset {ds.name}@{ds.id}"
    if not scenes:
        counts = {s: ds.scene_split.count(s) for s in SPLITS}
        other = next(s for s in SPLITS if s != split)
        raise ValueError(f"{label} has no {'held-out' if split == 'heldout' else 'training'} scenes (scenes per split: "
                         f"{counts}); evaluate split={other}, or generate a dataset with "
                         f"{'heldout_scenes' if split == 'heldout' else 'train_scenes'} > 0")
    # Trajectories are stored per scene in episode order, successes only: pair them with their episodes.
    solved = {i: [e for e in ds.episodes if e["scene"] == i and e["success"]] for i in scenes}
    first = {i: int(np.flatnonzero(ds.traj_scene.numpy() == i)[0]) if solved[i] else 0 for i in scenes}
    available = [len(solved[i]) for i in scenes]
    if sum(available) == 0:
        raise ValueError(f"{label} has {split} scenes but no solved expert trajectories in them to take problems from")
    rng = np.random.default_rng(seed)
    take = _spread(available, sum(available) if count is None else count, rng)
    times = {s["scene_index"]: s.get("planning_time") for s in ds.manifest.get("scenes", [])}
    robot = ds.manifest.get("robot", {}).get("name")
    problems = []
    for i, k in zip(scenes, take):
        for j in sorted(rng.choice(len(solved[i]), size=k, replace=False).tolist()):
            episode = solved[i][j]
            traj = ds.trajectories[first[i] + j].numpy()
            t = times.get(i)
            problems.append(Problem(ds.scenes[i], traj[0], traj[-1], split=split, scene_index=i, robot=robot,
                                    name=f"{ds.name}@{ds.id}/scene{i}/episode{episode['episode']}",
                                    expert_trajectory=traj,
                                    expert_time=None if t is None else float(t[episode["episode"]])))
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
