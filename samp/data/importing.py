"""Demonstrations recorded elsewhere, as a versioned samp dataset (`python -m samp.data import`).

Sources (docs/datasets.md, "Importing demonstrations"):

* `.npz` or HDF5 (`.h5`/`.hdf5`) with the keys
    - `joint_positions`: (K, T, n) radians, or (N, n) with `episode_ends` (K,), the exclusive end row of each
      trajectory (the layout of zarr replay buffers);
    - `scene`: one scene reference for every trajectory, or `scenes` (S,) with `episode_scene` (K,) indices;
    - optional `timestamps` ((K, T) or (N,) seconds, strictly increasing within a trajectory) and
      `joint_names` (n,) (columns are reordered to the robot's joints by name).
* a LeRobot-format dataset folder (`meta/info.json`, `data/**/*.parquet`): the `observation.state` column
  (or `key=`), grouped by `episode_index`, ordered by `frame_index`; its columns are the robot's joints by
  the names in `meta/info.json`, or the first n when it has no names and `columns=` says nothing.

A scene reference is a scene file (`samp.scene.files`) or `GENERATOR:SEED` (a generated scene).

Each trajectory is checked as the expert's output is: finite, every recorded step within `max_jump` radians
of the previous one, resampled to the expert's waypoint count by arc length, then every state along every
segment within the joint limits and at least `check_margin` from obstacles and free of self-collision
(`first_invalid_segment`). A refused one is kept in the dataset's episode records as a failure with its
reason (the obstacle it hits named), exactly as a problem the expert failed; the kept ones are its
trajectories. The expert then plans `eval_problems_per_scene` evaluation problems in each scene, so an
imported dataset trains and evaluates like a generated one. The manifest's parents are the source files'
sha256.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from samp.data.import_sources import Recorded, read_source

__all__ = ["ImportConfig", "Recorded", "check_recorded", "generated_scene_ref", "import_dataset", "read_source",
           "scene_from_ref", "source_parents"]

def check_recorded(world, robot, rec: Recorded, waypoints: int, resolution: float, margin: float,
                   max_jump: float) -> tuple[np.ndarray | None, str]:
    """(the (waypoints, n) trajectory, "") if `rec` passes the expert's checks, else (None, why)."""
    from samp.expert.trajectory import first_invalid_segment, resample, segment_states

    q = rec.q
    if q.ndim != 2 or len(q) < 2:
        return None, f"needs at least 2 recorded steps, has {len(q)}"
    if not np.all(np.isfinite(q)):
        step = int(np.flatnonzero(~np.isfinite(q).all(axis=1))[0])
        return None, f"step {step} is not finite (NaN or inf)"
    if rec.timestamps is not None:
        t = np.asarray(rec.timestamps)
        if not np.all(np.isfinite(t)):  # NaN compares false, so the increase check below would pass it
            return None, f"timestamp {int(np.flatnonzero(~np.isfinite(t))[0])} is not finite (NaN or inf)"
        if len(t) != len(q) or np.any(np.diff(t) <= 0):
            return None, f"timestamps must be one per step and strictly increasing ({len(t)} for {len(q)} steps)"
    with np.errstate(over="ignore"):  # two finite steps 1e308 apart: an inf jump, refused below like any other
        jumps = np.abs(np.diff(q, axis=0)).max(axis=1)
    if jumps.max() > max_jump:
        step = int(np.argmax(jumps > max_jump))
        joint = robot.joint_names[int(np.argmax(np.abs(q[step + 1] - q[step])))]
        return None, (f"jump of {_rad(jumps[step])} rad in {joint} between steps {step} and {step + 1} (more than "
                      f"max_jump={max_jump})")
    traj = resample(q, waypoints)
    if first_invalid_segment(world, traj, resolution, margin) is None:
        return traj, ""
    states, owner = segment_states(traj, resolution)
    hits = np.flatnonzero(world.in_collision(states, margin=margin))
    distance = world.min_distance(states[hits])  # (H,) metres
    deepest = hits[int(np.argmin(np.where(np.isfinite(distance), distance, np.inf)))]
    # where along the recording: the state's arc length, measured on the recorded steps
    seg_start = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(traj, axis=0), axis=1))])
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(q, axis=0), axis=1))])

    def step(i: int) -> int:
        at = seg_start[owner[i]] + np.linalg.norm(states[i] - traj[owner[i]])
        return int(min(np.searchsorted(arc, at - 1e-12), len(q) - 1))

    where = f"at recorded step {step(hits[0])} of {len(q)}"
    if step(deepest) != step(hits[0]):
        where += f" (worst at step {step(deepest)})"
    return None, f"{where}: {_what_is_hit(world, robot, states[deepest], margin)}"


def _rad(x: float) -> str:
    """An angle for a message: 3 decimals, or 3 significant digits where a recording holds absurd values (1e300)."""
    return f"{x:.3f}" if abs(x) < 1e4 else f"{x:.3g}"


def _row(q: np.ndarray, i: int) -> list | None:
    """Row i of a recording as a list, None for a recording with no steps (it is refused, and recorded so)."""
    return q[i].tolist() if len(q) else None


def _what_is_hit(world, robot, q: np.ndarray, margin: float) -> str:
    """Why one configuration is invalid, naming the joint or the obstacle."""
    from samp.scene import Scene
    from samp.sim.world import World

    if world.outside_limits(q[None])[0]:
        lim = robot.joint_limits.double().cpu().numpy()
        j = int(np.argmax(np.maximum(lim[:, 0] - q, q - lim[:, 1])))
        return f"{robot.joint_names[j]} at {_rad(q[j])} rad is outside its limits [{lim[j, 0]:.3f}, {lim[j, 1]:.3f}]"
    scene = world.scene
    for o in scene.all_obstacles:
        with World(robot, Scene(name=o.name, obstacles=(o,), bounds=scene.bounds)) as alone:
            if alone.in_collision(q[None], margin=margin, self_collision=False)[0]:
                d = float(alone.min_distance(q[None])[0])
                if d < 0:
                    return f"the robot passes through obstacle {o.name!r} ({-d:.3f} m deep)"
                return f"the robot passes {d:.4f} m from obstacle {o.name!r}, inside the {margin} m margin"
    return "the robot collides with itself"


def source_parents(sources: list[Path]) -> list[str]:
    """`sha256:<hex> <name>` per source file (every file of a LeRobot folder, hashed together)."""
    from samp.paths import file_sha256

    out = []
    for path in sources:
        if path.is_dir():
            h = hashlib.sha256()
            for f in sorted(p for p in path.rglob("*") if p.is_file()):
                h.update(f"{f.relative_to(path).as_posix()}\0{file_sha256(f)}\n".encode())
            out.append(f"sha256:{h.hexdigest()} {path.name}/")
        else:
            out.append(f"sha256:{file_sha256(path)} {path.name}")
    return out


@dataclass
class ImportConfig:
    """What `python -m samp.data import` takes besides its sources (conf/data.yaml's `import` node)."""

    name: str
    robot: str = "panda"
    scene: str | None = None  # the scene of every trajectory, in place of the sources' own scene keys
    val: list[str] | None = None  # scene references whose trajectories validate; None: the last scene, if 2+
    resolutions: tuple[int, ...] = (40,)
    eval_problems_per_scene: int = 4  # planned by the expert in every scene, for the evaluation
    expert: str = "default"
    max_jump: float = 0.5  # radians, between consecutive recorded steps
    key: str = "observation.state"  # the LeRobot feature holding joint positions
    columns: list[int] | None = None
    seed: int = 0


def import_dataset(sources: list[Path], cfg: ImportConfig, root: Path | None = None, progress: bool = True):
    """Check, resample and write the trajectories of `sources` as dataset `cfg.name` -> (folder, summary)."""
    import os
    import shutil
    import sys
    import time
    from dataclasses import asdict

    from tqdm import tqdm

    from samp.data.generation import _robot
    from samp.data.merging import build_manifest
    from samp.data.registry import datasets_root, finalize_dataset
    from samp.expert.config import load_expert_config
    from samp.paths import check_name
    from samp.provenance import code_version, package_versions

    check_name(cfg.name, "dataset name")
    robot, expert = _robot(cfg.robot), load_expert_config(cfg.expert)
    recorded = [r for s in sources for r in read_source(Path(s), robot, cfg.scene, cfg.key, cfg.columns)]
    if not recorded:
        raise ValueError(f"the sources {[str(s) for s in sources]} hold no trajectories")
    refs = list(dict.fromkeys(r.scene for r in recorded))
    val = set(cfg.val if cfg.val is not None else (refs[-1:] if len(refs) > 1 else []))
    unknown = sorted(val - set(refs))
    if unknown:
        raise ValueError(f"val names scenes {unknown} that no trajectory was recorded in; scenes: {refs}")
    config = {"kind": "import", **asdict(cfg), "sources": source_parents([Path(s) for s in sources]),
              "waypoints": expert.waypoints, "expert_config": asdict(expert), "scene_refs": refs}
    config_hash = hashlib.sha256(json.dumps(config, sort_keys=True, default=list).encode()).hexdigest()
    root = Path(root) if root else datasets_root()
    tmp = root / cfg.name / f".tmp-{os.getpid()}-{time.time_ns()}"
    tmp.mkdir(parents=True)
    try:
        infos, summary = [], {"kept": 0, "refused": 0, "reasons": []}
        # a bar only on a terminal: redirected to a log, its \r frames would be noise (the summary line says it all)
        drawn = progress and sys.stderr.isatty()
        with tqdm(total=len(recorded), desc=f"import {cfg.name}", unit="traj", disable=not drawn) as bar:
            for index, ref in enumerate(refs):
                split = "val" if ref in val else "train"
                mine = [r for r in recorded if r.scene == ref]
                infos.append(_import_scene(_Target(robot, expert, cfg, tmp, config_hash), ref, index, split, mine,
                                           summary, bar))
        manifest = build_manifest(config, config_hash, cfg.seed, robot.asset_hash, infos,
                                  parents=config["sources"])
        manifest.update(code_version=code_version(), versions=package_versions())
        if summary["kept"] == 0:
            raise ValueError(f"every one of the {summary['refused']} trajectories was refused; first: "
                             f"{summary['reasons'][0]}")
        return finalize_dataset(tmp, cfg.name, manifest, root), summary
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def generated_scene_ref(generator: str, seed: int) -> str:
    """The reference of a generated scene, `GENERATOR:SEED`, which `scene_from_ref` reads back."""
    return f"{generator}:{int(seed)}"


def scene_from_ref(ref: str):
    """A scene reference -> Scene: `GENERATOR:SEED` (a generated scene) or a scene file."""
    from samp.scene import available_generators
    from samp.scene.files import load_scene_file, resolve_scene_file
    from samp.scene.registry import _load_config, scene_from_config

    generator, _, seed = ref.partition(":")
    if generator in available_generators() and seed.isdigit():
        return scene_from_config(_load_config(generator), int(seed))
    return load_scene_file(resolve_scene_file(ref))


@dataclass
class _Target:
    """What every scene of one import shares: the robot, the expert config, the settings, where the scene files
    go and the import's config hash."""

    robot: object
    expert: object
    cfg: ImportConfig
    out: Path
    config_hash: str


def _import_scene(target: _Target, ref: str, index: int, split: str, mine: list[Recorded], summary: dict,
                  bar) -> dict:
    """Check one scene's trajectories, plan its evaluation problems, write its scene file -> its manifest entry."""
    from samp.data.generation import EVAL_PLANS, EVAL_PROBLEMS, _plan_problems
    from samp.data.mcap_io import SceneRecord, link_poses, stacked, write_scene_file
    from samp.data.registry import SCENE_FILE_VERSION
    from samp.expert.planner import make_planner
    from samp.expert.seeding import derive_seed

    robot, expert, cfg, out = target.robot, target.expert, target.cfg, target.out
    scene = scene_from_ref(ref)
    episodes, kept = [], []
    with make_planner(robot, scene, expert) as planner:
        for k, rec in enumerate(mine):
            traj, reason = check_recorded(planner.world, robot, rec, expert.waypoints, expert.resolution,
                                          expert.check_margin, cfg.max_jump)
            episodes.append({"episode": k, "success": traj is not None, "reason": reason, "kind": "imported",
                             "purpose": "demonstration", "start": _row(rec.q, 0), "goal": _row(rec.q, -1),
                             "goal_pose": None, "detour": None,
                             "stats": {"source": rec.source, "recorded_steps": int(len(rec.q))}})
            if traj is None:
                summary["refused"] += 1
                summary["reasons"].append(f"{rec.source} (scene {ref}): {reason}")
            else:
                summary["kept"] += 1
                kept.append(traj)
            bar.update(1)
        stages = {"problems": 0.0}
        eval_episodes, eval_timings, solutions = _plan_problems(
            robot, scene, planner, expert, cfg.eval_problems_per_scene, derive_seed(cfg.seed, index),
            (EVAL_PROBLEMS, EVAL_PLANS), "evaluation", lambda: None, f"scene {ref}", 0.0, stages)
    file = f"scene_{index:04d}.mcap"
    n = robot.dof
    metadata = {"format_version": SCENE_FILE_VERSION, "dataset": cfg.name, "config_hash": target.config_hash,
                "robot": cfg.robot, "robot_asset_hash": robot.asset_hash, "scene_index": index, "split": split,
                "generator": "import", "scene_namespace": "import", "scene_seed": 0}
    write_scene_file(out / file, SceneRecord(
        scene, index, split, list(robot.joint_names), metadata,
        grids={r: scene.anchor_grid(r, cache=False) for r in cfg.resolutions},
        trajectories=stacked(kept, n), episodes=episodes,
        eval_trajectories=stacked(solutions, n), eval_episodes=eval_episodes,
        poses=lambda q: link_poses(robot, q), ee_link=robot.ee_link, link_meshes=robot.link_meshes))
    return {"scene_index": index, "name": scene.name, "file": file, "split": split, "generator": "import",
            "seed": 0, "scene_ref": ref, "content_hash": scene.content_hash(), "robot_asset_hash": robot.asset_hash,
            "episodes": len(episodes), "trajectories": len(kept), "eval_problems": len(eval_episodes),
            "eval_solved": len(solutions), "detours": 0,
            "eval_detours": sum(e["detour"] is True for e in eval_episodes),
            "eval_planning_time": [t["planning_time"] for t in eval_timings]}
