"""DAgger-style aggregation, a stage of the training recipe (`dagger.rounds`, conf/train.yaml).

A policy trained only on the expert's demonstrations has never seen the states it drifts into. One round:

1. the teacher, a policy trained the same way on the current dataset (a run of its own,
   `runs/<name>_round<r>/`, or the run `dagger.teacher` names), is rolled out on problems of its training
   scenes (starts and goals of the dataset's stored demonstrations);
2. where a rollout collides, the expert plans again from a state it visited `back` steps before the first
   contact (further back when that state is too close to an obstacle to start from); where it stops short
   of the goal, from its last state; from a share (`clean_share`) of the clean rollouts, from their
   half-way state;
3. those plans and the dataset's own demonstrations are imported as a new dataset
   (`<dataset>_dagger_<key>`, `samp.data.importing`), which the run then trains on.

Each piece is found again rather than redone when the same command runs again: a completed teacher run
whose recorded `dagger_key` matches (a hash of its resolved config and of the dataset and robot SDF it
would use), and the aggregated dataset, whose name carries a hash of the teacher's checkpoint and the
round's settings. `rounds: 2` trains the round-1 teacher itself with one round, and so on down.
"""

from __future__ import annotations

import hashlib
import json
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from samp.cli import paste
from samp.console import plural

__all__ = ["collect", "rollout_problems", "restarts", "stage"]

# keys of the training config that say where a run goes and how it is watched, not what it learns
_NOT_LEARNED = ("name", "paths", "run_dir", "resume", "trust_checkpoint", "tracking", "evaluation", "logger")
_TEACHER_DROPS = ("name", "resume", "run_dir", "trust_checkpoint", "dagger.rounds", "dagger.teacher")
_SUFFIX = re.compile(r"_dagger_[0-9a-f]{8}$")


def rollout_problems(ds, per_scene: int, rng: np.random.Generator, scenes: list[int] | None = None):
    """`per_scene` (start, goal) pairs of the stored demonstrations of each training scene (of `scenes`, the
    teacher's; None: all), as `Problem`s."""
    from samp.eval.problems import Problem

    problems = []
    robot = ds.manifest["robot"]["name"]
    for i in ds.scene_indices("train") if scenes is None else scenes:
        rows = np.flatnonzero(ds.traj_scene.numpy() == i)
        for k in sorted(rng.choice(rows, size=min(per_scene, len(rows)), replace=False).tolist()):
            q = ds.trajectories[k].numpy()
            problems.append(Problem(ds.scenes[i], q[0], q[-1], split="train", scene_index=i, robot=robot,
                                    name=f"{ds.name}@{ds.id}/scene{i}/demo{k}", scene_hash=ds.scene_hashes[i]))
    return problems


def restarts(result, check: dict, clean_share: float, back: int, rng: np.random.Generator) -> list[np.ndarray]:
    """The visited states to plan from, most wanted first: before the first contact (then further back),
    the last state of a rollout that stopped short, or (for a share of the clean ones) its half-way state."""
    traj = result.trajectory
    if check["collision"]:  # never state 0: that is the stored start, whose demonstration the dataset has
        first = int(check["first_collision_step"])
        steps = dict.fromkeys(max(1, first - back * j) for j in (1, 2, 3))
        return [traj[k] for k in steps if k < first]
    if result.termination != "reached":
        return [traj[-1], traj[len(traj) // 2]]
    return [traj[len(traj) // 2]] if len(traj) > 4 and rng.random() < clean_share else []


def scene_refs(ds) -> list[str]:
    """`GENERATOR:SEED` of every generated scene of `ds`, its scene file for one read from a file (`scene_files`);
    ValueError when a scene is imported or the generators' settings were overridden, which such a reference
    does not carry."""
    from samp.data.importing import generated_scene_ref
    from samp.data.spec import FILE_GENERATOR

    infos = ds.manifest["scenes"]
    files = iter(_file_refs(ds.manifest["config"]))
    if any(s.get("generator") in (None, "import") for s in infos):
        raise ValueError(f"dataset {ds.name}@{ds.id} has imported scenes; DAgger rounds name scenes by their "
                         "generator and seed or their scene file, and handle generated datasets only: set "
                         "dagger.rounds=0")
    if ds.manifest["config"].get("generator_overrides"):
        raise ValueError(f"dataset {ds.name}@{ds.id} overrides its generators' settings, which a GENERATOR:SEED "
                         "scene reference does not carry; DAgger rounds handle datasets of the generators' own "
                         "settings only: set dagger.rounds=0")
    refs = [next(files, None) if s["generator"] == FILE_GENERATOR else generated_scene_ref(s["generator"], s["seed"])
            for s in infos]
    if None in refs or next(files, None) is not None:
        raise ValueError(f"dataset {ds.name}@{ds.id}: its manifest's scene files do not match its file scenes; "
                         "regenerate it")
    return refs


def _file_refs(config: dict) -> list[str]:
    """The scene files of a spec's file scenes, in scene order (`DatasetSpec.scene_jobs`: after the generated
    scenes, split by split, folders and globs expanded as the spec's resolved config recorded them)."""
    from samp.data.spec import SPLIT_ORDER

    refs = config.get("scene_file_expansion") or config.get("scene_files") or {}
    return [r for split in SPLIT_ORDER for r in refs.get(split, [])]


def collect(system, ds, per_scene: int, back: int, clean_share: float, seed: int, scenes: list[int] | None = None,
            progress: bool = True):
    """Roll `system`'s policy out in the training scenes of `ds` (those of `scenes`; None: all) and let the
    dataset's expert plan from the states it visits -> (trajectories, their scene indices, counts).
    Deterministic for a given `seed`."""
    import torch
    from tqdm import tqdm

    from samp.eval.checks import TrajectoryChecker
    from samp.eval.config import RolloutConfig
    from samp.eval.problems import dataset_grids
    from samp.eval.rollouts import rollout
    from samp.expert.planner import derive_seed, make_planner
    from samp.robot import load_robot

    rng = np.random.default_rng(seed)
    problems = rollout_problems(ds, per_scene, rng, scenes)
    t0 = time.perf_counter()
    results = rollout(system.planner(), problems, RolloutConfig(), grid_source=dataset_grids(ds))
    scenes_used = len({p.scene_index for p in problems})
    print(f"dagger: rolled out {plural(len(problems), 'problem')} of {plural(scenes_used, 'training scene')} in "
          f"{time.perf_counter() - t0:.0f} s", flush=True)
    robot = load_robot(ds.manifest["robot"]["name"], dtype=torch.float64)
    expert = ds.manifest["config"]["expert_config"]
    new_q, new_scene = [], []
    counts = {"collided": 0, "short": 0, "clean": 0, "planned": 0, "unplanned": 0}
    by_scene: dict[int, list[int]] = {}
    for j, p in enumerate(problems):
        by_scene.setdefault(p.scene_index, []).append(j)
    with TrajectoryChecker(robot) as checker, tqdm(total=len(problems), desc="dagger: expert from visited states",
                                                   unit="rollout", disable=not progress) as bar:
        for i, rows in by_scene.items():
            checks = checker.check(ds.scenes[i], [results[j].trajectory for j in rows])
            with make_planner(robot, ds.scenes[i], expert) as planner:
                for j, check in zip(rows, checks):
                    kind = "collided" if check["collision"] else "short" if results[j].termination != "reached" \
                        else "clean"
                    counts[kind] += 1
                    for attempt, q in enumerate(restarts(results[j], check, clean_share, back, rng)):
                        plan = planner.plan(q, problems[j].q_goal, seed=derive_seed(seed, j, attempt))
                        if plan.success:
                            new_q.append(np.asarray(plan.trajectory, dtype=np.float64))
                            new_scene.append(i)
                            counts["planned"] += 1
                            break
                    else:
                        counts["unplanned"] += kind != "clean"
                    bar.update()
    print(f"dagger: rollouts {counts['collided']} collided, {counts['short']} stopped short, {counts['clean']} "
          f"clean; {counts['planned']} expert plans from visited states; {counts['unplanned']} failed rollouts "
          "without one", flush=True)
    return new_q, new_scene, counts


def write_source(path: Path, ds, refs: list[str], new_q: list, new_scene: list) -> None:
    """The dataset's own demonstrations, then the new ones, as an import source (`.npz`, never overwritten)."""
    trajectories = [t.numpy() for t in ds.trajectories] + list(new_q)
    scenes = ds.traj_scene.tolist() + list(new_scene)
    with open(path, "xb") as f:
        np.savez_compressed(f, joint_positions=np.concatenate(trajectories),
                            episode_ends=np.cumsum([len(t) for t in trajectories]), scenes=np.array(refs),
                            episode_scene=np.array(scenes), joint_names=np.array(ds.joint_names))


def _key(payload) -> str:
    return hashlib.sha256(json.dumps(payload, sort_keys=True, default=str).encode()).hexdigest()


def aggregate(teacher: Path, settings, root: Path, seed: int, dataset: str | None = None) -> str:
    """One round from the trained run `teacher`: the aggregated dataset as `NAME@ID`, imported into `root`
    (found there instead when the same teacher and settings made it before). The teacher is rolled out in the
    training scenes of `dataset` (`NAME@ID`; None: of the teacher's own dataset)."""
    from samp.data import DatasetError, open_dataset
    from samp.data.importing import ImportConfig, import_dataset
    from samp.paths import file_sha256, find_checkpoint
    from samp.policy.registry import load_system
    from samp.runs import RunFolder

    system = load_system(teacher)
    ds = open_dataset(dataset or system.binding.dataset_id, root)
    refs = scene_refs(ds)
    # the teacher is rolled out where it was trained: the first `max_scenes` training scenes when it had that
    max_scenes = None if dataset else \
        ((RunFolder(teacher).read().get("config") or {}).get("datamodule") or {}).get("max_scenes")
    scenes = ds.scene_indices("train")[:max_scenes] if max_scenes else None
    rules = {"per_scene": int(settings.per_scene), "back": int(settings.back),
             "clean_share": float(settings.clean_share), "seed": int(seed), "max_scenes": max_scenes}
    name = f"{_SUFFIX.sub('', ds.name)}_dagger_{_key([file_sha256(find_checkpoint(teacher)), ds.id, rules])[:8]}"
    try:
        found = open_dataset(name, root)
    except DatasetError:
        pass
    else:
        print(f"dagger: {found.name}@{found.id} was aggregated from {teacher} before: using it", flush=True)
        return f"{found.name}@{found.id}"
    new_q, new_scene, _ = collect(system, ds, rules["per_scene"], rules["back"], rules["clean_share"], seed, scenes)
    if not new_q:
        print("dagger: no plan was added, so the round adds nothing to the dataset", flush=True)
    val = [refs[i] for i in ds.scene_indices("val")]
    with tempfile.TemporaryDirectory(dir=root, prefix=".dagger-") as tmp:
        source = Path(tmp) / f"{name}.npz"
        write_source(source, ds, refs, new_q, new_scene)
        cfg = ImportConfig(name=name, robot=ds.manifest["robot"]["name"], val=val, resolutions=tuple(ds.resolutions),
                           seed=seed)
        folder, summary = import_dataset([source], cfg, root)
    print(f"dagger: imported {name}@{folder.name}: {summary['kept']} of {summary['kept'] + summary['refused']} "
          f"trajectories ({len(ds.trajectories)} of {ds.name}@{ds.id}, {len(new_q)} from visited states; "
          f"{summary['refused']} refused)", flush=True)
    for reason in summary["reasons"]:
        print(f"  refused {reason}", flush=True)
    return f"{name}@{folder.name}"


def _teacher_key(overrides: list[str], cfg) -> str:
    """What the teacher learns from: its resolved config without where it goes and how it is watched, with
    the dataset and robot SDF it would use (as resolved for this run)."""
    from omegaconf import OmegaConf, open_dict

    from samp.train.config import compose_train_config

    composed = compose_train_config(overrides)
    with open_dict(composed):
        composed.paths = cfg.paths  # as `train(paths=...)` sets them: keys that interpolate a path agree
    composed = OmegaConf.to_container(composed, resolve=True)
    learned = {k: v for k, v in composed.items() if k not in _NOT_LEARNED}
    learned["datamodule"] = {**learned["datamodule"], "dataset": _dataset_ref(cfg)}
    learned["system"] = {**learned["system"], "robot_sdf": str(cfg.system.get("robot_sdf"))}
    return _key(learned)


def _dataset_ref(cfg) -> str:
    """The datamodule's dataset as `NAME@ID` (a name or prefix resolved in the run's datasets folder)."""
    from samp.data import read_manifest, resolve_ref
    from samp.train.prerequisites import _datasets_root

    manifest = read_manifest(resolve_ref(str(cfg.datamodule.dataset), _datasets_root(cfg)))
    return f"{manifest['name']}@{manifest['id']}"


def _find_teacher(folder: Path, key: str) -> Path | None:
    """The newest completed run in `folder` whose recorded `dagger_key` is `key`."""
    from samp.runs import RunFolder

    for run in sorted(folder.glob("*/"), reverse=True):
        if (run / "run.json").is_file():
            record = RunFolder(run).read()
            if record.get("status") == "completed" and record.get("dagger_key") == key:
                return run
    return None


def stage(cfg, overrides: list[str]) -> None:
    """The DAgger rounds of `cfg` (writable, dataset and robot SDF already resolved): train or find the
    teacher, aggregate, and point `cfg.datamodule.dataset` at the aggregated dataset; records the teacher
    and the dataset under `cfg.dagger`."""
    from samp.runs.lineage import override_key
    from samp.train.prerequisites import _datasets_root
    from samp.train.recipe import _repo_path, train

    settings = cfg.dagger
    rounds = int(settings.rounds)
    if rounds < 1:
        return
    for key, low in (("per_scene", 1), ("back", 1)):
        if int(settings[key]) < low:
            raise ValueError(f"dagger.{key} must be >= {low}, got {settings[key]}")
    if not 0 <= float(settings.clean_share) <= 1:
        raise ValueError(f"dagger.clean_share must be in [0, 1], got {settings.clean_share}")
    if settings.get("scenes") not in (None, "teacher", "run"):  # before a teacher is trained, not after
        raise ValueError(f"dagger.scenes must be teacher or run, got {settings.scenes!r}")
    if cfg.datamodule.get("max_trajectories") is not None:
        raise ValueError("dagger.rounds cannot be combined with datamodule.max_trajectories (the first N training "
                         "trajectories of the aggregated dataset are other ones); use datamodule.max_scenes")
    root = _datasets_root(cfg)
    if settings.get("teacher") and rounds == 1:
        teacher = _repo_path(str(settings.teacher))  # relative to the project folder, as resume= is
        if not (teacher / "run.json").is_file():
            raise FileNotFoundError(f"dagger.teacher={settings.teacher}: not a run folder (no run.json there)")
        print(f"dagger: round 1 rolls out the given teacher {teacher}", flush=True)
    else:
        from samp.data import open_dataset

        scene_refs(open_dataset(_dataset_ref(cfg), root))  # refused before a teacher is trained for nothing
        name = f"{cfg.name}_round{rounds - 1}"
        kept = [o for o in overrides if override_key(o) not in _TEACHER_DROPS and not override_key(o).startswith(
            "evaluation.")]
        teacher_overrides = [*kept, f"name={name}", f"dagger.rounds={rounds - 1}", "evaluation.problems=0",
                             "evaluation.benchmark=null"]
        if settings.get("teacher"):
            teacher_overrides.append(f"dagger.teacher={settings.teacher}")
        key = _teacher_key(teacher_overrides, cfg)
        paths = {"runs_dir": cfg.paths.runs_dir, "datasets_dir": cfg.paths.datasets_dir}
        teacher = _find_teacher(Path(cfg.paths.runs_dir) / name, key)
        if teacher is not None:
            print(f"dagger: round {rounds}: the teacher {teacher} was trained before with the same config: using it",
                  flush=True)
        else:
            print(f"dagger: round {rounds}: training its teacher first: "
                  f"`{paste('python -m samp.train', *teacher_overrides)}`", flush=True)
            teacher = train(teacher_overrides, paths=paths, dagger_key=key).path
    where = _dataset_ref(cfg) if settings.get("teacher") and rounds == 1 and settings.get("scenes") == "run" else None
    cfg.datamodule.dataset = aggregate(teacher, settings, root, int(cfg.seed), where)
    cfg.dagger.teacher = str(teacher)
    print(f"dagger: round {rounds}: training on {cfg.datamodule.dataset}", flush=True)
