"""Dataset generation: scenes planned in worker processes, sharded, resumable, merged into one dataset.

The unit of work is a scene (`SceneJob`): draw it, compute its anchor grids, sample its demonstration
problems (train and val scenes) and, from a seed stream of their own, its evaluation problems (every
scene), plan each with the same expert, and write `scene_NNNN.mcap` (atomically) with a small JSON
sidecar of wall-clock planner times. Evaluation problems go on topics of their own, never into the
training data (`samp.data.mcap_io`). Scene files collect in a work folder keyed by the spec's config hash,
`<root>/<name>/.work/<hash16>/`, so:
  * shard i of n does the scenes with index % n == i; shards can run anywhere and at any time (with a
    shared file system they write side by side; otherwise copy their scene files together);
  * a killed run loses only the scenes that were being planned: a rerun skips every finished file;
  * `merge` checks that every scene of the spec is there and turns the folder into a dataset
    (`samp.data.registry.finalize_dataset`), after which the work folder is removed. One merge at a time
    per work folder: a lock file that shared file systems honour (`samp.data.merging.merge_lock`); a merge
    killed at any point is finished by the next (`_merge_locked`).

Wall-clock times go to the manifest, not into the MCAP files, so the data files, and with them the
dataset id, depend only on the spec and seed (as long as no problem hits the planner's time limit, whose
outcome depends on the machine's load), and on every x86 CPU: the processes that plan take MKL's
CPU-independent path (`samp.data.lifecycle.reproducible_mkl`): the workers (`workers` >= 2, also for one
scene) and `python -m samp.data generate`; a caller's own process planning with `workers=1` keeps its own.
"""

from __future__ import annotations

import copy
import json
import os
import shutil
import time
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from multiprocessing import get_context
from multiprocessing.managers import SyncManager
from pathlib import Path

import numpy as np

from samp.cli import paste
from samp.data.lifecycle import die_with_parent, drain, end_workers, exit_without_teardown, reproducible_mkl
from samp.data.mcap_io import link_poses, stacked
from samp.data.merging import (EVAL_PREFIX, MERGING, MergeLockTimeout, build_manifest, link_or_copy, merge_lock,
                                move_aside, remove_trash)
from samp.data.registry import SCENE_FILE_VERSION, DatasetError, datasets_root, finalize_dataset
from samp.data.spec import DatasetSpec, SceneJob, load_spec
from samp.data.workfolder import SIDECAR, clear_stale, generation_lock, removed_on_error, unfinished, write_json

__all__ = ["GenerationError", "GenerationInterrupted", "generate", "merge", "work_dir"]

TIMING_KEYS = ("planning_time", "solve_time", "simplify_time")  # wall clock: manifest only
# derive_seed(scene seed, KEY[, problem]): the seed streams of a scene's problems and plans. Demonstrations
# and evaluation problems draw from different streams, so no evaluation problem repeats a demonstration.
DEMO_PROBLEMS, DEMO_PLANS, EVAL_PROBLEMS, EVAL_PLANS = 1, 2, 3, 4


class GenerationError(ValueError):
    """A spec that cannot be generated (e.g. its scenes leave no valid start), or missing shards."""


class MergeBusy(GenerationError):
    """Another process held the merge lock of this work folder for longer than `merge` waits
    (`samp.data.merging.WAIT_TIMEOUT_S`); the message names it."""


class GenerationInterrupted(KeyboardInterrupt):
    """Ctrl-C (SIGINT) during generation: scheduling stopped, the workers were ended, finished scenes kept.
    Its message is the one line to print."""


def work_dir(spec: DatasetSpec, root: Path | str | None = None) -> Path:
    return Path(root or datasets_root()) / spec.name / ".work" / spec.config_hash()[:16]


def _file_metadata(spec: DatasetSpec, job: SceneJob, asset_hash: str, config_hash: str) -> dict:
    """The `samp.dataset` metadata record of a scene file: deterministic, no times or versions."""
    return {"format_version": SCENE_FILE_VERSION, "dataset": spec.name, "config_hash": config_hash,
            "robot": spec.robot, "robot_asset_hash": asset_hash, "scene_index": job.index, "split": job.split,
            "generator": job.generator, "scene_namespace": spec.namespace, "scene_seed": job.seed}


# ------------------------------------------------------------------------------------------ one scene
_ROBOTS: dict[str, object] = {}  # per process: robots are loaded once
_SPECS: dict[str, tuple] = {}  # per process: the spec in use, validated (`_loaded`)
_TICKS = None  # per worker process: queue of finished-problem ticks for the progress bar


def _init_worker(ticks, parent: int | None = None) -> None:
    global _TICKS
    reproducible_mkl()
    if parent is not None:
        die_with_parent(parent)
    _TICKS = ticks
    import torch  # here, not at the top: the generating process itself plans nothing and needs no torch

    from samp.data import mcap_io  # noqa: F401 (with torch, what every scene needs, before the exit handler)
    from samp.expert import planner  # noqa: F401

    torch.set_num_threads(1)
    exit_without_teardown()  # after the imports above: the last exit handler registered runs first


def _loaded(spec_dict: dict):
    """(spec, expert config, config hash) of a spec mapping, validated once per process and copied out: a
    worker plans many scenes of one spec, and validating it costs ~0.4 s (OmegaConf) each time."""
    key = json.dumps(spec_dict, sort_keys=True)
    if key not in _SPECS:
        spec = load_spec(spec_dict)
        _SPECS.clear()  # one spec at a time
        _SPECS[key] = spec, spec.expert_config(), spec.config_hash()
    return copy.deepcopy(_SPECS[key])


def _robot(name: str):
    import torch

    from samp.robot import load_robot

    if name not in _ROBOTS:
        _ROBOTS[name] = load_robot(name, dtype=torch.float64)
    return _ROBOTS[name]


def _episode(result, index: int, problem, purpose: str) -> tuple[dict, dict]:
    """PlanResult -> (episode record for the MCAP file, wall-clock times for the sidecar)."""
    as_list = lambda a: None if a is None else np.asarray(a, dtype=np.float64).tolist()  # noqa: E731
    stats = {k: v for k, v in result.stats.items() if k not in TIMING_KEYS}
    record = {"episode": index, "success": bool(result.success), "reason": result.reason, "kind": problem.kind,
              "purpose": purpose, "start": as_list(result.q_start), "goal": as_list(result.q_goal),
              "goal_pose": as_list(problem.goal_pose), "detour": problem.detour, "stats": stats}
    return record, {k: float(result.stats.get(k, 0.0)) for k in TIMING_KEYS}


def _plan_problems(robot, scene, planner, cfg, count: int, seed: int, keys: tuple[int, int], purpose: str, tick,
                   where: str, detour_share: float, stages: dict,
                   given: list | None = None) -> tuple[list[dict], list[dict], list[np.ndarray]]:
    """Sample `count` problems from the seed stream keys[0] (or take the `given` problems of the scene's file,
    `samp.data.given_problems`) and plan each (seed stream keys[1]) -> (episode records, wall-clock times,
    (T, n) trajectories of the solved ones)."""
    from samp.data.given_problems import given_problems
    from samp.expert.planner import PlanResult, derive_seed
    from samp.expert.problems import sample_problems

    if count == 0:
        return [], [], []
    t0 = time.perf_counter()
    try:
        if given is not None:
            problems = given_problems(robot, planner.world, given, cfg)
        else:
            problems = sample_problems(robot, scene, count, derive_seed(seed, keys[0]), cfg,
                                       world=getattr(planner, "world", None), detour_share=detour_share)
    except ValueError as err:
        if given is not None:
            raise GenerationError(f"{where}: {err}") from None
        raise GenerationError(f"{where}: the scene cannot host valid planning problems: {err}. Change the "
                              "spec's generators or generator_overrides, or lower the expert's clearance") from None
    stages["problems"] += time.perf_counter() - t0
    episodes, timings, trajectories = [], [], []
    for i, p in enumerate(problems):
        if p.q_goal is None:
            result = PlanResult(False, None, p.reason, {"attempts": 0}, p.q_start)
        else:
            result = planner.plan(p.q_start, p.q_goal, seed=derive_seed(seed, keys[1], i),
                                  straight_free=None if p.detour is None else not p.detour)  # checked when sampled
        record, times = _episode(result, i, p, purpose)
        episodes.append(record)
        timings.append(times)
        if result.success:
            trajectories.append(result.trajectory)
        tick()
    return episodes, timings, trajectories


def _given(job: SceneJob) -> list | None:
    """The problems a file scene's file gives, when the job takes them (`problems_from_files`); else None."""
    if not job.file_problems:
        return None
    from samp.scene.files import file_problems, resolve_scene_file

    return file_problems(resolve_scene_file(job.scene_file))


def run_scene(spec_dict: dict, job: SceneJob, out_dir: str, tick=None) -> dict:
    """Generate one scene file into `out_dir`; returns its sidecar record. Threads are pinned to one so
    results do not depend on the number of workers."""
    import torch

    from samp.data.mcap_io import SceneRecord, write_scene_file
    from samp.expert.planner import make_planner
    from samp.scene.registry import scene_from_config

    (spec, cfg, config_hash), out = _loaded(spec_dict), Path(out_dir)
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    tick = tick or (lambda: _TICKS.put(1) if _TICKS is not None else None)
    try:
        robot = _robot(spec.robot)
        where = (f"dataset spec {spec.name!r}, scene {job.index} (generator {job.generator!r}, seed {job.seed}"
                 + (f", {job.scene_file})" if job.scene_file else ")"))
        try:
            scene = (spec.file_scene(job.scene_file) if job.scene_file else
                     scene_from_config(spec.generator_config(job.generator), job.seed))
        except ValueError as err:
            raise GenerationError(f"{where}: {err}") from None
        t0 = time.perf_counter()
        grids = {n: scene.anchor_grid(n, cache=False) for n in spec.resolutions}
        stages = {"grids": time.perf_counter() - t0, "problems": 0.0}  # wall clock per stage: for the bench
        with make_planner(robot, scene, cfg) as planner:  # the same expert, config and post-processing for both
            episodes, timings, trajectories = _plan_problems(
                robot, scene, planner, cfg, job.trajectories, job.seed, (DEMO_PROBLEMS, DEMO_PLANS), "demonstration",
                tick, where, spec.detour_share, stages)
            eval_episodes, eval_timings, solutions = _plan_problems(
                robot, scene, planner, cfg, job.eval_problems, job.seed, (EVAL_PROBLEMS, EVAL_PLANS), "evaluation",
                tick, where, spec.detour_share, stages, given=_given(job))
        sidecar = {"scene_index": job.index, "name": scene.name, "generator": job.generator, "seed": job.seed,
                   "split": job.split, "content_hash": scene.content_hash(), "file": job.file,
                   "robot_asset_hash": robot.asset_hash,  # so the merge need not load the robot
                   "episodes": len(episodes), "trajectories": len(trajectories),
                   "eval_problems": len(eval_episodes), "eval_solved": len(solutions),
                   "detours": sum(e["detour"] is True for e in episodes),
                   "eval_detours": sum(e["detour"] is True for e in eval_episodes), "stage_time": stages,
                   **{k: [t[k] for t in timings] for k in TIMING_KEYS},
                   **{EVAL_PREFIX + k: [t[k] for t in eval_timings] for k in TIMING_KEYS}}
        # The sidecar first: a scene counts as done when its MCAP file exists (renamed into place last).
        write_json(out / (job.file + SIDECAR), sidecar)
        t0 = time.perf_counter()
        with removed_on_error(out / (job.file + ".tmp"), out / (job.file + SIDECAR)):  # nothing left by a full disk
            write_scene_file(out / job.file, SceneRecord(
                scene, job.index, job.split, list(robot.joint_names),
                _file_metadata(spec, job, robot.asset_hash, config_hash),
                grids=grids, trajectories=stacked(trajectories, robot.dof), episodes=episodes,
                eval_trajectories=stacked(solutions, robot.dof), eval_episodes=eval_episodes,
                poses=lambda q: link_poses(robot, q), ee_link=robot.ee_link, link_meshes=robot.link_meshes))
        stages["write"] = time.perf_counter() - t0
        write_json(out / (job.file + SIDECAR), sidecar)  # again, with the writing time
        return sidecar
    finally:
        torch.set_num_threads(threads)


# ------------------------------------------------------------------------------------------ shards
def finished_dataset(spec: DatasetSpec, root: Path | None = None) -> Path | None:
    """The newest finished dataset of `spec`'s name made from exactly this spec (same config hash), or None."""
    from samp.data.registry import list_datasets

    made = [d for d in list_datasets(Path(root) if root else None)
            if d["name"] == spec.name and d.get("config_hash") == spec.config_hash()]
    return Path(max(made, key=lambda d: d["created"])["path"]) if made else None


def _intact(spec: DatasetSpec, done: Path) -> Path:
    """`done`, the finished dataset of `spec`, after verifying it as `python -m samp.data verify` does; a
    damaged one is a DatasetError naming the damage and what to do (it is never deleted here)."""
    from samp.data.registry import verify_dataset

    problems = verify_dataset(done)
    if problems:
        more = f" and {len(problems) - 1} more" if len(problems) > 1 else ""
        raise DatasetError(f"{spec.name}: the dataset already generated from this spec, {spec.name}@{done.name} "
                           f"({done}), is damaged ({problems[0]}{more}); nothing was planned. Restore it from a copy, "
                           "or move it aside (or delete it) and run the same command again to generate it anew")
    return done


def _already_there(spec: DatasetSpec, root: Path | None, work: Path) -> Path | None:
    """A finished dataset of this spec, verified, when no generation of it is under way (its work folder is gone)."""
    done = finished_dataset(spec, root)
    if done is not None and not any(work.glob("*.mcap")):
        _intact(spec, done)
        print(f"{spec.name}: already generated from this spec as {spec.name}@{done.name} ({done}); nothing to plan "
              "or merge", flush=True)
        return done
    return None


def generate(spec: DatasetSpec | str | dict, shard: int | None = None, num_shards: int = 1, workers: int = 1,
             root: Path | None = None, progress: bool = True) -> Path | None:
    """Generate the scenes of `shard` (None: all of them) with `workers` processes, resuming from any
    finished scene files. When every scene of the spec is done, merge into a dataset and return its
    folder; otherwise (a shard of several) return None. A spec generated before (a finished dataset of the
    same config hash, no work under way) is found and returned, nothing planned."""
    spec = spec if isinstance(spec, DatasetSpec) else load_spec(spec)
    if num_shards < 1 or (shard is not None and not 0 <= shard < num_shards):
        raise ValueError(f"shard must be in [0, num_shards) with num_shards >= 1, got shard={shard} num_shards={num_shards}")
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    work = work_dir(spec, root)
    done = _already_there(spec, root, work)
    if done is not None:
        return done
    work.mkdir(parents=True, exist_ok=True)
    label = f"{spec.name}" + ("" if shard is None else f" shard {shard}/{num_shards}")
    with generation_lock(work, spec.name, shard, num_shards):
        return _generate_locked(spec, shard, num_shards, workers, root, progress, work, label)


def _generate_locked(spec: DatasetSpec, shard: int | None, num_shards: int, workers: int, root: Path | None,
                     progress: bool, work: Path, label: str) -> Path | None:
    """`generate` under the generation lock of its shard (`samp.data.workfolder`)."""
    from samp.console import Progress, plural

    jobs = [j for j in spec.scene_jobs() if shard is None or j.index % num_shards == shard]
    clear_stale(work, [j.file for j in jobs])  # before anything new is written: a full disk's leftovers go first
    write_json(work / "spec.json", spec.resolved(), shared=True)
    todo = unfinished(work, jobs, label)  # a damaged scene file is removed and planned again
    if len(todo) < len(jobs):
        print(f"{label}: resuming, {len(jobs) - len(todo)} of {plural(len(jobs), 'scene')} already done in {work}")
    plans = sum(j.trajectories + j.eval_problems for j in todo)  # demonstrations and evaluation problems
    bar = Progress(plans, label, unit="plan", enabled=progress)  # a bar on a terminal, else a line now and then
    spec_dict = spec.resolved()
    spec_dict = {k: spec_dict[k] for k in DatasetSpec.__dataclass_fields__ if k in spec_dict}
    _SPECS.clear()  # validated afresh: conf/ may have changed since this process last generated
    try:
        if workers == 1 or not todo:  # in this process (its MKL path: module docstring)
            for job in todo:
                run_scene(spec_dict, job, str(work), tick=lambda: bar.update(1))
        else:  # in workers, also for a single scene, so that workers >= 2 always plans on MKL's common path
            _run_pool(spec_dict, todo, work, min(workers, len(todo)), bar)
    except KeyboardInterrupt:
        done = sum((work / j.file).is_file() for j in jobs)
        raise GenerationInterrupted(
            f"{label}: interrupted; {done} of {plural(len(jobs), 'scene')} finished and kept in {work}; run the same "
            "command again to resume") from None
    finally:
        bar.close()
    missing = [j for j in spec.scene_jobs() if not (work / j.file).is_file()]
    if missing:
        print(f"{label}: done; {plural(len(missing), 'scene')} of other shards {'is' if len(missing) == 1 else 'are'} "
              f"not finished yet (run `{paste('python -m samp.data merge', dataset=spec.name)}` when they are)")
        return None
    return merge(spec, root)  # a shard finishing at the same time may be merging: merge waits for it


def _run_pool(spec_dict: dict, todo: list[SceneJob], work: Path, workers: int, bar) -> None:
    """Scenes in `workers` spawned processes, which die with this one (even by SIGKILL). On any error or
    Ctrl-C, nothing more is scheduled and the workers are ended at once; finished scene files stay."""
    ctx = get_context("spawn")  # a clean interpreter per worker: no inherited torch or pybullet state
    manager = SyncManager(ctx=ctx)
    manager.start(die_with_parent, (os.getpid(),))
    ticks = manager.Queue()
    pool = ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(ticks, os.getpid()))
    try:
        pending = {pool.submit(run_scene, spec_dict, job, str(work)) for job in todo}
        while pending:
            done, pending = wait(pending, timeout=0.2, return_when=FIRST_COMPLETED)
            drain(ticks, bar)
            for future in done:
                future.result()  # a failed scene stops the run; finished scenes stay on disk
        drain(ticks, bar)
    except BaseException:
        end_workers(pool)
        raise
    else:
        pool.shutdown(wait=True)
    finally:
        manager.shutdown()


# ------------------------------------------------------------------------------------------ merge
def merge(spec: DatasetSpec | str | dict, root: Path | None = None) -> Path:
    """Join the finished scene files of every shard into one dataset; names the missing scenes if any.
    Waits while another process merges the same spec, then returns the dataset it made."""
    spec = spec if isinstance(spec, DatasetSpec) else load_spec(spec)
    root = Path(root) if root else datasets_root()
    work = work_dir(spec, root)
    jobs = spec.scene_jobs()
    remove_trash(work.parent)
    if not work.is_dir():  # merged already (by a shard finishing at the same time), or never generated
        return _merged_already(spec, root) or _merge_locked(spec, root, work, jobs)  # the latter names what is missing
    try:
        with merge_lock(work, spec.name):
            if not work.is_dir():  # the process we waited for merged it
                return _merged_already(spec, root) or _merge_locked(spec, root, work, jobs)
            return _merge_locked(spec, root, work, jobs)
    except MergeLockTimeout as err:
        raise MergeBusy(str(err)) from None


def _merged_already(spec: DatasetSpec, root: Path) -> Path | None:
    """The dataset this spec was merged into (its work folder is gone), or None."""
    done = finished_dataset(spec, root)
    if done is not None:
        _intact(spec, done)
        print(f"{spec.name}: already merged into {spec.name}@{done.name}")
    return done


def _merge_locked(spec: DatasetSpec, root: Path, work: Path, jobs: list[SceneJob]) -> Path:
    """Under the merge lock (or with no work folder, to name what is missing): assemble the dataset inside the
    work folder, publish it by one rename (`finalize_dataset`), then move the work folder aside and remove it.
    A killed merge leaves a stale lock and a partial `.merging-*` folder (the next merge starts again), or a
    published dataset (the next finds its id), or a `.removed-*` folder (the next removes it)."""
    from samp.provenance import code_version, package_versions

    missing = [j.index for j in unfinished(work, jobs, spec.name)]  # a damaged scene is removed, never merged
    if missing:
        raise GenerationError(f"cannot merge {spec.name!r}: {len(missing)} of {len(jobs)} scenes are not generated "
                              f"yet (indices {missing[:20]}{' ...' if len(missing) > 20 else ''}) in {work}; run "
                              f"`{paste('python -m samp.data generate', dataset=spec.name)}` (or the missing shards) first")
    sidecars = [json.loads((work / (j.file + SIDECAR)).read_text()) for j in jobs]
    for left in work.glob(MERGING + "*"):  # of a killed merge: its lock was stale, so nothing else uses it
        shutil.rmtree(left, ignore_errors=True)
    tmp = work / f"{MERGING}{os.getpid()}-{time.time_ns()}"
    tmp.mkdir()
    try:
        for j in jobs:
            link_or_copy(work / j.file, tmp / j.file)
        hashes = {s.get("robot_asset_hash") for s in sidecars}
        asset = next(iter(hashes)) if len(hashes) == 1 and None not in hashes else _asset_hash(spec.robot)
        manifest = build_manifest(spec.resolved(), spec.config_hash(), spec.seed, asset, sidecars, parents=[])
        manifest.update(code_version=code_version(), versions=package_versions(), scene_file_version=SCENE_FILE_VERSION)
        dest = finalize_dataset(tmp, spec.name, manifest, root)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    move_aside(work)
    remove_trash(work.parent)
    return dest


def _asset_hash(robot: str) -> str:
    from samp.robot import load_robot

    return _ROBOTS[robot].asset_hash if robot in _ROBOTS else load_robot(robot).asset_hash
