"""Reading a dataset into tensors once (`open_dataset`), and writing one back (`write_dataset`).

Trajectories are small and decoded for the whole dataset when it is opened, into one contiguous
(N, T, n) tensor; anchor grids are large and decoded per scene and resolution on first use, then kept.
Nothing is decoded per sample: training code indexes these tensors.
"""

from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import numpy as np
import torch

from samp.data.mcap_io import SceneRecord, read_scene_file, write_scene_file
from samp.data.registry import DatasetError, datasets_root, finalize_dataset, read_manifest, resolve_ref
from samp.scene import Scene

__all__ = ["Dataset", "open_dataset", "write_dataset"]


class Dataset:
    """A finished dataset, decoded.

    Attributes:
        path: its folder; manifest: its manifest (dict); id, name: from the manifest.
        scenes: list[Scene] in scene-index order; scene_split: list of "train" | "heldout" per scene.
        trajectories: (N, T, n) float64 radians, the successful episodes of every scene in order.
        traj_scene: (N,) long scene index of each trajectory; traj_split: (N,) "train" | "heldout".
        episodes: every planning problem (failures included) as its JSON record plus "scene".
        joint_names: the robot's joint names, in column order.
    """

    def __init__(self, path: Path, manifest: dict, records: list[SceneRecord]):
        self.path, self.manifest = path, manifest
        self.name, self.id = manifest["name"], manifest["id"]
        self._files = [path / s["file"] for s in manifest["scenes"]]
        self.scenes: list[Scene] = [r.scene for r in records]
        self.scene_split: list[str] = [r.split for r in records]
        self.joint_names: list[str] = records[0].joint_names if records else []
        self.metadata: list[dict] = [r.metadata for r in records]
        self.resolutions: list[int] = records[0].resolutions if records else []
        n = len(self.joint_names)
        trajs = [r.trajectories for r in records if len(r.trajectories)]
        self.trajectories = torch.from_numpy(np.concatenate(trajs)) if trajs else torch.zeros(0, 0, n, dtype=torch.float64)
        self.traj_scene = torch.cat([torch.full((len(r.trajectories),), i, dtype=torch.long) for i, r in enumerate(records)]) \
            if records else torch.zeros(0, dtype=torch.long)
        self.traj_split = np.array([self.scene_split[i] for i in self.traj_scene.tolist()], dtype="<U7")
        self.episodes: list[dict] = [{**e, "scene": i} for i, r in enumerate(records) for e in r.episodes]
        self._grids: dict[tuple[int, int], torch.Tensor] = {}

    def __len__(self) -> int:
        return len(self.trajectories)

    def __repr__(self) -> str:
        return (f"Dataset({self.name}@{self.id}: {len(self.scenes)} scenes ({self.scene_split.count('heldout')} held out), "
                f"{len(self)} trajectories, grids n_e={self.resolutions})")

    def scene_indices(self, split: str) -> list[int]:
        if split not in ("train", "heldout"):
            raise ValueError(f"split must be 'train' or 'heldout', got {split!r}")
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


def open_dataset(ref: str | Path, root: Path | None = None) -> Dataset:
    """Open `name` (newest), `name@id` (a unique id prefix is enough) or a dataset folder."""
    path = resolve_ref(ref, root)
    manifest = read_manifest(path)
    if "scenes" not in manifest:
        raise DatasetError(f"{path} is a {manifest.get('kind', 'different kind of')} dataset, not expert trajectories")
    records = [read_scene_file(path / s["file"], resolutions=[]) for s in manifest["scenes"]]
    for s, r in zip(manifest["scenes"], records):
        if r.scene_index != s["scene_index"] or len(r.episodes) != s["episodes"] or len(r.trajectories) != s["trajectories"]:
            raise DatasetError(f"{path / s['file']} does not hold what the manifest says (scene {s['scene_index']}, "
                               f"{s['episodes']} episodes, {s['trajectories']} trajectories); run "
                               "`python -m samp.data verify` on it")
    return Dataset(path, manifest, records)


def write_dataset(ds: Dataset, name: str | None = None, root: Path | None = None) -> Path:
    """Write `ds` as a dataset of its own (its id as parent). Equal content gives byte-identical files,
    hence the same id: written, read back and written again, a dataset is unchanged."""
    from samp.data.generation import build_manifest
    from samp.provenance import code_version, package_versions

    name, root = name or ds.name, (Path(root) if root else datasets_root())
    tmp = root / name / f".tmp-{os.getpid()}-{time.time_ns()}"
    tmp.mkdir(parents=True)
    try:
        first = 0
        for i, scene in enumerate(ds.scenes):
            info = ds.manifest["scenes"][i]
            count = int((ds.traj_scene == i).sum())
            episodes = [{k: v for k, v in e.items() if k != "scene"} for e in ds.episodes if e["scene"] == i]
            grids = {n: ds.grid(i, n) for n in ds.resolutions}
            write_scene_file(tmp / info["file"], scene, info["scene_index"], ds.scene_split[i], ds.joint_names, grids,
                             episodes, list(ds.trajectories[first:first + count].numpy()), ds.metadata[i])
            first += count
        m = ds.manifest
        manifest = build_manifest(m["config"], m["config_hash"], m["seed"], m["robot"]["asset_hash"], m["scenes"],
                                  parents=[f"{ds.name}@{ds.id}"])
        manifest.update(code_version=code_version(), versions=package_versions())
        return finalize_dataset(tmp, name, manifest, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
