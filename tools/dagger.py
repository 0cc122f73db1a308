"""One round of DAgger-style aggregation for a trained SAMP policy, as an import source.

The policy is rolled out on problems of its own training scenes (starts and goals of the dataset's stored
demonstrations). Where a rollout collides, the expert plans again from a state it visited a few steps before
the first contact, stepping further back when that state is itself too close to an obstacle for the expert
to start from; where it stops short of the goal, from its last state; from a share of the clean rollouts,
from one state visited half way. Those plans, with the dataset's own demonstrations, are written as one
`.npz` for `python -m samp.data import`, so the aggregated dataset is versioned, checked and trained like
any other:

    python tools/dagger.py --run RUN --out dagger.npz
    python -m samp.data import source=dagger.npz name=cpu64_dagger val=...   (the command it prints)
    python -m samp.train experiment=samp_cpu datamodule.dataset=cpu64_dagger build_missing.dataset=false

The expert is the dataset's own (its manifest's expert config) and plans with seeds derived from `--seed`,
so a rerun writes the same file. Scenes are named `GENERATOR:SEED`, which the import regenerates; a dataset
built from scene files is refused.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np


def rollout_problems(ds, per_scene: int, rng: np.random.Generator):
    """`per_scene` (start, goal) pairs of each training scene's stored demonstrations, as `Problem`s."""
    from samp.eval.problems import Problem

    problems = []
    robot = ds.manifest["robot"]["name"]
    for i in ds.scene_indices("train"):
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


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", required=True, help="a trained SAMP run folder")
    parser.add_argument("--dataset", default=None, help="the dataset to aggregate (default: the run's own)")
    parser.add_argument("--out", required=True, type=Path, help="the .npz to write (refused if it exists)")
    parser.add_argument("--per-scene", type=int, default=16, help="rollouts per training scene")
    parser.add_argument("--back", type=int, default=3, help="steps before the first contact to plan from")
    parser.add_argument("--clean-share", type=float, default=0.25,
                        help="share of clean rollouts that also give a plan from their half-way state")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    if args.out.exists():
        parser.error(f"{args.out} exists; choose another --out or move it away (nothing is overwritten)")
    if args.out.suffix != ".npz":
        parser.error(f"--out must end in .npz, got {args.out}")
    if args.per_scene < 1 or args.back < 1 or not 0 <= args.clean_share <= 1:
        parser.error("--per-scene and --back must be >= 1 and --clean-share in [0, 1]")

    import torch
    from tqdm import tqdm

    from samp.data.dataset import open_dataset
    from samp.eval.checks import TrajectoryChecker
    from samp.eval.config import RolloutConfig
    from samp.eval.problems import dataset_grids
    from samp.eval.rollouts import rollout
    from samp.expert.planner import derive_seed, make_planner
    from samp.policy.registry import load_system
    from samp.robot import load_robot

    torch.set_num_threads(1)
    system = load_system(Path(args.run))
    ds = open_dataset(args.dataset or system.binding.dataset_id)
    infos = ds.manifest["scenes"]
    if any(s.get("generator") in (None, "file", "import") for s in infos):
        sys.exit(f"dataset {ds.name}@{ds.id} has scenes that are not generated (files or imports); this tool "
                 "names scenes GENERATOR:SEED and handles generated datasets only")
    if ds.manifest["config"].get("generator_overrides"):
        sys.exit(f"dataset {ds.name}@{ds.id} overrides its generators' settings, which a GENERATOR:SEED scene "
                 "reference does not carry; this tool handles datasets of the generators' own settings only")
    refs = [f"{s['generator']}:{s['seed']}" for s in infos]
    rng = np.random.default_rng(args.seed)
    policy = system.planner()
    problems = rollout_problems(ds, args.per_scene, rng)
    t0 = time.perf_counter()
    results = rollout(policy, problems, RolloutConfig(), grid_source=dataset_grids(ds))
    print(f"rolled out {len(problems)} problems of {len(ds.scene_indices('train'))} training scenes in "
          f"{time.perf_counter() - t0:.0f} s")

    robot = load_robot(ds.manifest["robot"]["name"], dtype=torch.float64)
    expert = ds.manifest["config"]["expert_config"]
    new_q, new_scene, counts = [], [], {"collided": 0, "short": 0, "clean": 0, "planned": 0, "unplanned": 0}
    by_scene: dict[int, list[int]] = {}
    for j, p in enumerate(problems):
        by_scene.setdefault(p.scene_index, []).append(j)
    with TrajectoryChecker(robot) as checker, tqdm(total=len(problems), desc="expert from visited states",
                                                   unit="rollout") as bar:
        for i, rows in by_scene.items():
            checks = checker.check(ds.scenes[i], [results[j].trajectory for j in rows])
            with make_planner(robot, ds.scenes[i], expert) as planner:
                for j, check in zip(rows, checks):
                    kind = "collided" if check["collision"] else "short" if results[j].termination != "reached" \
                        else "clean"
                    counts[kind] += 1
                    for attempt, q in enumerate(restarts(results[j], check, args.clean_share, args.back, rng)):
                        plan = planner.plan(q, problems[j].q_goal, seed=derive_seed(args.seed, j, attempt))
                        if plan.success:
                            new_q.append(np.asarray(plan.trajectory, dtype=np.float64))
                            new_scene.append(i)
                            counts["planned"] += 1
                            break
                    else:
                        counts["unplanned"] += kind != "clean"
                    bar.update()
    print(f"rollouts: {counts['collided']} collided, {counts['short']} stopped short, {counts['clean']} clean; "
          f"{counts['planned']} expert plans from visited states; {counts['unplanned']} failed rollouts without one")

    own_q = [t.numpy() for t in ds.trajectories]
    own_scene = ds.traj_scene.tolist()
    trajectories = own_q + new_q
    scenes = own_scene + new_scene
    ends = np.cumsum([len(t) for t in trajectories])
    args.out.parent.mkdir(parents=True, exist_ok=True)
    with open(args.out, "xb") as f:
        np.savez_compressed(f, joint_positions=np.concatenate(trajectories), episode_ends=ends,
                            scenes=np.array(refs), episode_scene=np.array(scenes),
                            joint_names=np.array(ds.joint_names))
    val = [refs[i] for i in ds.scene_indices("val")]
    print(f"wrote {args.out}: {len(own_q)} demonstrations of {ds.name}@{ds.id} and {len(new_q)} from visited states")
    print(f"next: python -m samp.data import source={args.out} name={ds.name}_dagger val={','.join(val)} "
          f"resolutions={','.join(map(str, ds.resolutions))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
