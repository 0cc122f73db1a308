"""Reading a dataset into tensors once (`open_dataset`), and writing one back (`write_dataset`).

Trajectories are small and decoded for the whole dataset when it is opened, into one contiguous
(N, T, n) tensor; anchor grids are large and decoded per scene and resolution on first use, then kept.
Nothing is decoded per sample: training code indexes these tensors. Evaluation problems are decoded
into `Dataset.eval_problems`, apart from the demonstrations: `trajectories` never holds them.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from samp.data.mcap_io import (DETOUR_FORMAT, TIMED_FORMAT, SceneRecord, link_poses, read_scene_file, stacked,
                               write_scene_file)
from samp.data.registry import (DatasetError, datasets_root, file_problems, finalize_dataset, read_manifest,
                                recreate_hint, resolve_ref)
from samp.names import SPLIT_ALIASES, SPLITS
from samp.scene import Scene

__all__ = ["Dataset", "canonical_split", "open_dataset", "scene_count_problems", "write_dataset"]


def canonical_split(split: str) -> str:
    """"train" | "val" | "test", with the older "heldout" read as "val"; ValueError otherwise."""
    if split not in SPLITS and split not in SPLIT_ALIASES:
        raise ValueError(f"split must be one of {', '.join(SPLITS)} (or the older 'heldout', read as 'val'), "
                         f"got {split!r}")
    return SPLIT_ALIASES.get(split, split)


class Dataset:
    """A finished dataset, decoded.

    Attributes:
        path: its folder; manifest: its manifest (dict); id, name: from the manifest.
        scenes: list[Scene] in scene-index order: train scenes, then val, then test.
        scene_split: list of "train" | "val" | "test" per scene. scene_hashes: list of `Scene.content_hash()`
            per scene, the scene's identity (from the manifest; computed for manifests without them).
        legacy_splits: True for an older dataset with two splits: its "heldout" scenes (read as "val") both
            validated and tested, and it stores no evaluation problems. False for datasets with three splits.
        trajectories: (N, T, n) float64 radians, the successful demonstrations of every scene in order.
        traj_scene: (N,) long scene index of each trajectory; traj_split: (N,) "train" | "val" (test scenes
            have no demonstrations).
        episodes: every demonstration problem (failures included) as its JSON record plus "scene".
        eval_problems: every evaluation problem in scene order, stored apart from the demonstrations: dicts
            {"scene": int, "index": int (within its scene), "split", "start": (n,) list, "goal": (n,) list
            or None (no valid goal was found), "goal_pose": (4, 4) nested list or None, "kind", "detour":
            bool or None (the straight start-goal line is blocked; None before scene-file format 3), "success":
            bool (the expert solved it), "reason": str (why not), "solution": (W, n) float64 array or None,
            "planning_time": the expert's seconds or None, "stats": the planner's statistics}.
        has_eval_problems: whether the dataset stores evaluation problems (False for legacy datasets).
        joint_names: the robot's joint names, in column order.
    """

    def __init__(self, path: Path, manifest: dict, records: list[SceneRecord]):
        self.path, self.manifest = path, manifest
        self.name, self.id = manifest["name"], manifest["id"]
        infos = manifest["scenes"]
        self._files = [path / s["file"] for s in infos]
        self.scenes: list[Scene] = [r.scene for r in records]
        self.scene_split: list[str] = [canonical_split(r.split) for r in records]
        self.scene_hashes: list[str] = [s.get("content_hash") or r.scene.content_hash() for s, r in zip(infos, records)]
        self.has_eval_problems = all(r.has_eval_topics and "eval_problems" in s for s, r in zip(infos, records))
        self.legacy_splits = any(r.split in SPLIT_ALIASES for r in records) or not self.has_eval_problems
        self.joint_names: list[str] = records[0].joint_names if records else []
        self.metadata: list[dict] = [r.metadata for r in records]
        self.resolutions: list[int] = records[0].resolutions if records else []
        n = len(self.joint_names)
        trajs = [r.trajectories for r in records if len(r.trajectories)]
        self.trajectories = torch.from_numpy(np.concatenate(trajs)) if trajs else torch.zeros(0, 0, n, dtype=torch.float64)
        self.traj_scene = torch.cat([torch.full((len(r.trajectories),), i, dtype=torch.long) for i, r in enumerate(records)]) \
            if records else torch.zeros(0, dtype=torch.long)
        self.traj_split = np.array([self.scene_split[i] for i in self.traj_scene.tolist()], dtype="<U5")
        self.episodes: list[dict] = [{**e, "scene": i} for i, r in enumerate(records) for e in r.episodes]
        self.eval_problems: list[dict] = [p for i, (s, r) in enumerate(zip(infos, records))
                                          for p in _eval_problems(i, self.scene_split[i], s, r)]
        self._grids: dict[tuple[int, int], torch.Tensor] = {}

    def __len__(self) -> int:
        return len(self.trajectories)

    def __repr__(self) -> str:
        splits = ", ".join(f"{self.scene_split.count(s)} {s}" for s in SPLITS)
        return (f"Dataset({self.name}@{self.id}: {len(self.scenes)} scenes ({splits}), {len(self)} trajectories, "
                f"{len(self.eval_problems)} evaluation problems, grids n_e={self.resolutions}"
                f"{', legacy splits' if self.legacy_splits else ''})")

    def scene_indices(self, split: str) -> list[int]:
        """The indices of the scenes in `split` ("train" | "val" | "test"; "heldout" reads as "val")."""
        split = canonical_split(split)
        return [i for i, s in enumerate(self.scene_split) if s == split]

    def grid(self, scene_index: int, n_e: int) -> torch.Tensor:
        """(n_e, n_e, n_e) float32 anchor grid of a scene, indexed (x, y, z); decoded once, then cached."""
        if not 0 <= scene_index < len(self.scenes):
            raise IndexError(f"scene index {scene_index} out of range: the dataset has {len(self.scenes)} scenes")
        if n_e not in self.resolutions:
            raise ValueError(f"dataset {self.name}@{self.id} stores grids at n_e in {self.resolutions}, not {n_e}; "
                             "regenerate it with that resolution in the spec's `resolutions`, or compute the grid "
                             "with `scene.anchor_grid(n_e)`")
        key = (scene_index, n_e)
        if key not in self._grids:
            self._grids[key] = read_scene_file(self._files[scene_index], resolutions=[n_e]).grids[n_e]
        return self._grids[key]

    def grids(self, n_e: int) -> torch.Tensor:
        """(S, n_e, n_e, n_e) the grids of every scene at one resolution."""
        return torch.stack([self.grid(i, n_e) for i in range(len(self.scenes))])


def _eval_problems(scene: int, split: str, info: dict, record: SceneRecord) -> list[dict]:
    """A scene file's evaluation records, each with the expert's solution and its planning time (from the
    manifest: wall-clock times are kept out of the data files)."""
    times = info.get("eval_planning_time") or [None] * len(record.eval_episodes)
    solutions = iter(record.eval_trajectories)
    out = []
    for e, time_s in zip(record.eval_episodes, times):
        out.append({"scene": scene, "index": e["episode"], "split": split, "start": e["start"], "goal": e["goal"],
                    "goal_pose": e.get("goal_pose"), "kind": e.get("kind"), "detour": e.get("detour"),
                    "success": bool(e["success"]),
                    "reason": e["reason"], "solution": next(solutions) if e["success"] else None,
                    "planning_time": None if e["goal"] is None or time_s is None else float(time_s),
                    "stats": e.get("stats", {})})
    return out


def _counts(s: dict, r: SceneRecord) -> tuple[tuple, tuple]:
    """(what the manifest says, what the file holds): scene index, episodes, trajectories, evaluation
    problems and solved ones."""
    held = (r.scene_index, len(r.episodes), len(r.trajectories), len(r.eval_episodes), len(r.eval_trajectories))
    said = (s.get("scene_index"), s.get("episodes"), s.get("trajectories"), s.get("eval_problems", 0),
            s.get("eval_solved", 0))
    return said, held


def _count_problem(path: Path, said: tuple, held: tuple) -> str:
    return (f"{path}: the manifest says (scene index, episodes, trajectories, evaluation problems, solved ones) "
            f"{said}, the file holds {held}")


def scene_count_problems(path: Path, manifest: dict, records: list[SceneRecord] | None = None) -> list[str]:
    """One line per scene file that is unreadable or does not hold what the manifest says it does."""
    problems = []
    for i, s in enumerate(manifest["scenes"]):
        try:
            r = records[i] if records is not None else read_scene_file(path / s["file"], resolutions=[])
        except ValueError as err:
            problems.append(str(err))
            continue
        said, held = _counts(s, r)
        if said != held:
            problems.append(_count_problem(path / s["file"], said, held))
    return problems


def open_dataset(ref: str | Path, root: Path | None = None) -> Dataset:
    """Open `name` (newest, or the id a lock file pins), `name@id` (a unique id prefix is enough), a dataset
    folder, or a remote reference `<remote>/datasets/NAME@ID` (pulled into `root` first; samp/data/sharing.py).

    Refuses (DatasetError) whatever `python -m samp.data verify` refuses: a manifest changed after
    writing, a file entry outside the folder, a file whose sha256 differs, an unreadable scene file (MCAP
    CRCs are checked) or one that does not hold what the manifest says; the message names the file,
    expected and actual, and how to restore or re-create the dataset."""
    path = resolve_ref(ref, root)
    manifest = read_manifest(path)
    if "scenes" not in manifest:
        raise DatasetError(f"{path} is a {manifest.get('kind', 'different kind of')} dataset, not expert trajectories")
    problems = file_problems(path, manifest)
    if problems:
        raise DatasetError(f"dataset {path} fails verification: {'; '.join(problems[:3])}"
                           f"{f' (and {len(problems) - 3} more)' if len(problems) > 3 else ''}; "
                           f"{recreate_hint(path, manifest)}")
    try:
        records = [read_scene_file(path / s["file"], resolutions=[]) for s in manifest["scenes"]]
    except ValueError as err:
        raise DatasetError(f"{err}; {recreate_hint(path, manifest)}") from None
    problems = scene_count_problems(path, manifest, records)
    if problems:
        raise DatasetError(f"dataset {path} fails verification: {problems[0]}; {recreate_hint(path, manifest)}")
    return Dataset(path, manifest, records)


def _scene_record(ds: Dataset, i: int) -> tuple[SceneRecord, dict]:
    """Scene i of `ds` as a scene file's content, and its manifest entry with counts and split from `ds`."""
    info = dict(ds.manifest["scenes"][i])
    episodes = [{k: v for k, v in e.items() if k != "scene"} for e in ds.episodes if e["scene"] == i]
    problems = [p for p in ds.eval_problems if p["scene"] == i]
    detours = int(ds.metadata[i].get("format_version", 1)) >= DETOUR_FORMAT  # records say so from format 3 on
    records = [{"episode": p["index"], "success": p["success"], "reason": p["reason"], "kind": p["kind"],
                "purpose": "evaluation", "start": p["start"], "goal": p["goal"], "goal_pose": p["goal_pose"],
                "stats": p["stats"], **({"detour": p["detour"]} if detours else {})} for p in problems]
    solutions = [p["solution"] for p in problems if p["success"]]
    record = SceneRecord(ds.scenes[i], info["scene_index"], ds.scene_split[i], ds.joint_names, ds.metadata[i],
                         grids={n_e: ds.grid(i, n_e) for n_e in ds.resolutions},
                         trajectories=ds.trajectories[ds.traj_scene == i].numpy(), episodes=episodes,
                         eval_trajectories=stacked(solutions, len(ds.joint_names)),
                         eval_episodes=records, has_eval_topics=ds.has_eval_problems)
    if record.format_version >= TIMED_FORMAT:  # what the file carries for viewers, from the robot
        from samp.data.generation import _robot

        robot = _robot(ds.manifest["robot"]["name"])
        record.poses, record.ee_link, record.link_meshes = (lambda q: link_poses(robot, q)), robot.ee_link, robot.link_meshes
    info.update(split=ds.scene_split[i], episodes=len(episodes), trajectories=len(record.trajectories))
    if ds.has_eval_problems:
        info.update(eval_problems=len(records), eval_solved=len(solutions))
    else:  # written as a dataset from before stored evaluation problems
        info = {k: v for k, v in info.items() if not k.startswith("eval_")}
    return record, info


def write_dataset(ds: Dataset, name: str | None = None, root: Path | None = None) -> Path:
    """Write `ds` as a dataset of its own (its id as parent). Equal content gives byte-identical files,
    hence the same id: written, read back and written again, a dataset is unchanged."""
    from samp.data.merging import build_manifest
    from samp.provenance import code_version, package_versions

    from samp.paths import check_name

    name, root = check_name(name or ds.name, "dataset name"), (Path(root) if root else datasets_root())
    tmp = root / name / f".tmp-{os.getpid()}-{time.time_ns()}"
    tmp.mkdir(parents=True)
    try:
        infos, formats = [], set()
        for i in range(len(ds.scenes)):
            record, info = _scene_record(ds, i)
            write_scene_file(tmp / info["file"], record)
            infos.append(info)
            formats.add(record.format_version)
        m = ds.manifest
        manifest = build_manifest(m["config"], m["config_hash"], m["seed"], m["robot"]["asset_hash"], infos,
                                  parents=[f"{ds.name}@{ds.id}"])
        manifest.update(code_version=code_version(), versions=package_versions(),
                        scene_file_version=max(formats) if len(formats) == 1 else sorted(formats))
        return finalize_dataset(tmp, name, manifest, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
