"""Benchmarks: `python tools/bench.py SUITE [--out FILE.json] [--device cpu|cuda]`.

Each suite times samp against a baseline measured in the same run and reports ratios, prints a table
and writes flat JSON: {"suite": ..., "metrics": {...}, "machine": {...}}. Suites:

    robot   FK and transform_points for B in {1, 50, 1024}; baseline: pybullet FK, one configuration at a time
    scene   anchor grids at n_e in {40, 100, 160} and World.in_collision on a 20-obstacle scene; baselines:
            the same distances one point at a time (timed on a sample, scaled to the grid), and a pairwise
            pybullet check of every link part against every obstacle without broadphase
    policy  SAMP policy training samples per second (scene-grouped batches vs random batches) and one
            policy step, at each --anchors n_e; peak memory
    data    expert trajectories per second on --workers processes and the planner's success rate per
            scene generator; open_dataset (decoded waypoints per second) and grid decoding against the
            same arrays read from a .npz file
    eval    rollouts per second of the batched engine (--problems problems over two scenes, grids at --n-e,
            the straight-line policy, or --policy-run RUN_DIR's trained policy at its own n_e) and of a
            full evaluation with pybullet checks; baseline: one problem at a time. The policy's
            per-problem solution time against the expert's planning time on --expert-problems of them
    robot_sdf  the paper's Table III in one run: the hash-grid robot SDF, NN-SDF, RDF (N = 8) and RDF
            (N = 24) trained or fitted on the same samples and evaluated on the same points (minutes on CPU);
            ratios against the hash grid
    perception  depth-camera capture and anchor-grid reconstruction per scene at n_e in --anchors (four
            scenes, --camera set, --unknown policy), against the exact scene.anchor_grid as the baseline, with
            the reconstruction error near obstacles; with --run, the policy's success rate on exact vs
            reconstructed grids for --problems held-out problems of --dataset
    baselines  Table I's timing on --baseline-problems problems: per-step inference (B = 1) and solution time
            of SAMP, MPiNet, MPNet (the runs in --runs; untrained default-size networks for step times
            otherwise) and the OMPL expert, expert_raw and ompl_sampling rows, as ratios to SAMP
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import sys
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch

SUITES: dict[str, Callable] = {}


def suite(fn: Callable) -> Callable:
    SUITES[fn.__name__] = fn
    return fn


def timeit(fn: Callable, device: torch.device, min_time: float = 0.2, repeats: int = 5) -> float:
    """Median seconds per call: calls are batched until a batch lasts `min_time`, over `repeats` batches."""
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    fn(); sync()  # warm-up
    n = 1
    while True:
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        sync()
        if (elapsed := time.perf_counter() - t0) >= min_time or n >= 1 << 16:
            break
        n *= 2
    times = [elapsed / n]
    for _ in range(repeats - 1):
        t0 = time.perf_counter()
        for _ in range(n):
            fn()
        sync()
        times.append((time.perf_counter() - t0) / n)
    return statistics.median(times)


def machine(device: torch.device) -> dict:
    info = {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count(),
            "torch": torch.__version__, "torch_threads": torch.get_num_threads(), "device": str(device)}
    if device.type == "cuda":
        info["gpu"] = torch.cuda.get_device_name(device)
    return info


@suite
def robot(args) -> tuple[dict, list[list]]:
    import pybullet as pb

    from samp.robot import load_robot

    device = torch.device(args.device)
    model = load_robot(args.robot, dtype=torch.float32).to(device)
    lo, hi = model.joint_limits.T.cpu().numpy()
    client = pb.connect(pb.DIRECT)
    body = pb.loadURDF(str(model.urdf.path), useFixedBase=True, physicsClientId=client)
    joint_index = {pb.getJointInfo(body, j, physicsClientId=client)[1].decode(): j
                   for j in range(pb.getNumJoints(body, physicsClientId=client))}
    arm = [joint_index[name] for name in model.joint_names]
    all_links = list(range(pb.getNumJoints(body, physicsClientId=client)))

    metrics, rows = {}, []
    for B in args.batch:
        q_np = np.random.default_rng(0).uniform(lo, hi, size=(B, model.dof))
        q = torch.as_tensor(q_np, dtype=torch.float32, device=device)

        def pybullet_fk():
            for qi in q_np:
                for j, v in zip(arm, qi):
                    pb.resetJointState(body, j, v, physicsClientId=client)
                pb.getLinkStates(body, all_links, computeForwardKinematics=True, physicsClientId=client)

        with torch.no_grad():
            t_pb = timeit(pybullet_fk, torch.device("cpu"))
            t_fk = timeit(lambda: model.fk(q), device)
            t_tp = timeit(lambda: model.transform_points(q), device)
        metrics.update({f"B{B}/pybullet_fk_ms": 1e3 * t_pb, f"B{B}/fk_ms": 1e3 * t_fk,
                        f"B{B}/transform_points_ms": 1e3 * t_tp, f"B{B}/fk_speedup": t_pb / t_fk,
                        f"B{B}/transform_points_speedup": t_pb / t_tp})
        rows.append([B, f"{1e3 * t_pb:.3f}", f"{1e3 * t_fk:.3f}", f"{t_pb / t_fk:.2f}x",
                     f"{1e3 * t_tp:.3f}", f"{t_pb / t_tp:.2f}x"])
    pb.disconnect(client)
    header = ["B", "pybullet FK [ms]", "samp fk [ms]", "fk vs pybullet", "transform_points [ms]", "tp vs pybullet"]
    return metrics, [header, *rows]


def _naive_point_sdf(scene, point) -> float:
    """Signed distance at one point, one obstacle at a time in plain numpy: the per-point baseline."""
    best = np.inf
    for o in scene.all_obstacles:
        T = o.pose.matrix()
        p = T[:3, :3].T @ (point - T[:3, 3])
        if o.kind == "box":
            q = np.abs(p) - np.asarray(o.size) / 2
            d = np.linalg.norm(np.maximum(q, 0)) + min(q.max(), 0)
        elif o.kind == "cylinder":
            q = np.array([np.hypot(p[0], p[1]) - o.radius, abs(p[2]) - o.height / 2])
            d = np.linalg.norm(np.maximum(q, 0)) + min(q.max(), 0)
        else:
            d = np.linalg.norm(p) - o.radius
        best = min(best, d)
    return best


def _naive_world_check(world, q: np.ndarray) -> np.ndarray:
    """Collision of each configuration by brute force: every moving link part against every obstacle body."""
    import pybullet as pb

    from samp.sim.bodies import MESH_MARGIN

    robot = world.robot
    parts = [b for n in robot.link_names if n != robot.base_link for b in world.links.bodies[n]]
    hits = []
    for qi in q:
        world.links.set_q(qi)
        hit = False
        for body in parts:
            for o in world.obstacles:
                pts = pb.getClosestPoints(body, o.body, 0.0, physicsClientId=world.client)
                if pts and min(p[8] for p in pts) + MESH_MARGIN + o.inflation < 0:
                    hit = True
        hits.append(hit or bool(world.links.colliding_pairs(exclude=robot.self_collision_exclude)))
    return np.array(hits)


def _bench_world(scn, args) -> tuple[dict, list[list]]:
    from samp.robot import load_robot
    from samp.sim import World

    robot = load_robot(args.robot, dtype=torch.float64)
    lo, hi = robot.joint_limits.numpy().T
    q = np.random.default_rng(1).uniform(lo, hi, size=(args.configs, robot.dof))
    with World(robot, scn) as world:
        t_world = timeit(lambda: world.in_collision(q), torch.device("cpu"), min_time=0.0, repeats=3)
        t0 = time.perf_counter()
        naive = _naive_world_check(world, q)
        t_naive = time.perf_counter() - t0
        hit = world.in_collision(q)
    if not np.array_equal(hit, naive):
        raise AssertionError(f"World.in_collision disagrees with the pairwise check on {(hit != naive).sum()} configs")
    per, per_naive = t_world / len(q), t_naive / len(q)
    metrics = {"world/in_collision_us": 1e6 * per, "world/naive_us": 1e6 * per_naive,
               "world/speedup": per_naive / per, "world/colliding_fraction": float(hit.mean())}
    return metrics, [[f"World.in_collision ({args.robot}, per config)", f"{1e6 * per:.0f} us",
                      f"{1e6 * per_naive:.0f} us", f"{per_naive / per:.1f}x"]]


@suite
def scene(args) -> tuple[dict, list[list]]:
    from samp.scene import anchor_points, generate_scene

    scn = generate_scene("tabletop", seed=0, num_obstacles=[19, 19])  # 19 clutter + table = 20, + the target
    sample = anchor_points(20, scn.bounds).reshape(-1, 3).numpy()[:2000]
    t0 = time.perf_counter()
    for p in sample:
        _naive_point_sdf(scn, p)
    per_point = (time.perf_counter() - t0) / len(sample)
    metrics, rows = {"obstacles": len(scn.all_obstacles), "naive_sdf_us_per_point": 1e6 * per_point}, []
    for n in args.anchors:
        t = timeit(lambda: scn.anchor_grid(n, cache=False), torch.device("cpu"), min_time=0.0, repeats=3)
        naive = per_point * n**3
        metrics.update({f"grid{n}/s": t, f"grid{n}/naive_s": naive, f"grid{n}/speedup": naive / t})
        rows.append([f"anchor_grid n_e={n}", f"{t:.3f} s", f"{naive:.1f} s (scaled)", f"{naive / t:.0f}x"])
    world_metrics, world_rows = _bench_world(scn, args)
    metrics.update(world_metrics)
    return metrics, [["what", "samp", "baseline", "speedup"], *rows, *world_rows]


@suite
def data(args) -> tuple[dict, list[list]]:
    """Expert generation on `--workers` processes, and decoding the dataset against the same arrays in .npz."""
    import tempfile

    from samp.data import generate, open_dataset, read_manifest
    from samp.data.mcap_io import read_scene_file

    spec = {"name": "bench", "robot": args.robot, "seed": 0, "train_scenes": args.scenes - 1, "heldout_scenes": 1,
            "trajectories_per_scene": args.trajectories, "generators": ["tabletop", "shelf", "cabinet", "blocks"],
            "resolutions": [40, 100]}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        folder = generate(spec, workers=args.workers, root=root, progress=True)
        t_gen = time.perf_counter() - t0
        m = read_manifest(folder)
        ds = open_dataset(folder)
        problems = m["counts"]["episodes"]
        metrics = {"generate/s": t_gen, "generate/problems": problems, "generate/workers": args.workers,
                   "generate/trajectories_per_s": m["counts"]["trajectories"] / t_gen,
                   "generate/problems_per_s": problems / t_gen}
        rows = [[f"expert generation, {args.workers} workers", f"{problems / t_gen:.2f} problems/s",
                 f"{m['counts']['trajectories']}/{problems} solved", ""]]
        for gen in spec["generators"]:
            eps = [e for e in ds.episodes if ds.manifest["scenes"][e["scene"]]["generator"] == gen]
            rate = sum(e["success"] for e in eps) / max(1, len(eps))
            metrics[f"success/{gen}"] = rate
            rows.append([f"  planner success, {gen}", f"{rate:.0%} of {len(eps)}", "", ""])

        npz = root / "same.npz"
        np.savez(npz, trajectories=ds.trajectories.numpy(), traj_scene=ds.traj_scene.numpy(),
                 **{f"grid{i}": ds.grid(i, 100).numpy() for i in range(len(ds.scenes))})
        samples = ds.trajectories.shape[0] * ds.trajectories.shape[1]  # one sample: one waypoint q_t

        def read_npz(grids: bool):
            with np.load(npz) as z:
                out = [torch.from_numpy(z["trajectories"]), torch.from_numpy(z["traj_scene"])]
                if grids:
                    out += [torch.from_numpy(z[f"grid{i}"]) for i in range(len(ds.scenes))]
            return out

        cpu = torch.device("cpu")
        t_mcap = timeit(lambda: open_dataset(folder), cpu, min_time=0.0, repeats=3)
        t_npz = timeit(lambda: read_npz(False), cpu, min_time=0.0, repeats=3)
        files = [folder / s["file"] for s in m["scenes"]]
        t_grid = timeit(lambda: [read_scene_file(f, resolutions=[100]) for f in files], cpu, min_time=0.0, repeats=3)
        t_grid_npz = timeit(lambda: read_npz(True), cpu, min_time=0.0, repeats=3) - t_npz
        metrics.update({"read/samples": samples, "read/mcap_samples_per_s": samples / t_mcap,
                        "read/npz_samples_per_s": samples / t_npz, "read/mcap_vs_npz": t_npz / t_mcap,
                        "read/grid100_mcap_s_per_scene": t_grid / len(files),
                        "read/grid100_npz_s_per_scene": max(t_grid_npz, 0.0) / len(files),
                        "dataset/bytes": sum(f.stat().st_size for f in files)})
        rows += [[f"open_dataset ({samples} waypoints)", f"{samples / t_mcap:,.0f} samples/s",
                  f"{samples / t_npz:,.0f} samples/s (npz)", f"{t_npz / t_mcap:.3f}x"],
                 ["grid n_e=100, per scene", f"{1e3 * t_grid / len(files):.1f} ms", f"{1e3 * max(t_grid_npz, 0) / len(files):.1f} ms (npz)",
                  f"{max(t_grid_npz, 1e-9) / t_grid:.2f}x"]]
    return metrics, [["what", "samp", "baseline", "ratio"], *rows]


@suite
def eval(args) -> tuple[dict, list[list]]:  # noqa: A001 (the suite's name; shadows the builtin here only)
    """Batched rollouts against one problem at a time, and the policy's solution time against the expert's."""
    from samp.eval import Problem, RolloutConfig, StraightLinePolicy, evaluate, rollout
    from samp.expert import ExpertPlanner, load_expert_config, sample_problems
    from samp.robot import load_robot
    from samp.scene import generate_scene

    device = torch.device(args.device)
    exact = load_robot(args.robot, dtype=torch.float64)
    scenes = [generate_scene("tabletop", seed=0), generate_scene("shelf", seed=1)]
    problems, per_scene = [], -(-args.problems // len(scenes))
    for i, scn in enumerate(scenes):  # start/goal pairs as the expert samples them; no planning needed
        drawn = sample_problems(exact, scn, per_scene + 5, seed=i, cfg=load_expert_config())
        problems += [Problem(scn, p.q_start, p.q_goal, split="train", robot=exact.name)
                     for p in drawn if p.q_goal is not None][:per_scene]
    problems = problems[:args.problems]
    if args.policy_run:  # a trained policy (its own n_e), else the straight line at --n-e
        from samp.eval import load_planner

        policy = load_planner(args.policy_run)
        if hasattr(policy, "system"):
            policy.system.to(device)
        args.n_e = policy.n_e
    else:
        policy = StraightLinePolicy(load_robot(args.robot, dtype=torch.float32).to(device), n_e=args.n_e)
    grids = {id(s): s.anchor_grid(args.n_e) for s in scenes}  # computed once (disk-cached), as a dataset's
    source = lambda p, n_e: grids[id(p.scene)]  # noqa: E731
    batched_cfg, single_cfg = RolloutConfig(), RolloutConfig(batch_size=1)
    label = policy.name if args.policy_run else "straight"

    def median_time(fn, repeats: int = 1 if args.policy_run else 3):
        """(median seconds, last result) over `repeats` calls: the machine may be shared."""
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            out = fn()
            times.append(time.perf_counter() - t0)
        return statistics.median(times), out

    rollout(policy, problems[:4], batched_cfg, source)  # warm-up
    t_batched, batched = median_time(lambda: rollout(policy, problems, batched_cfg, source))
    t_single, single = median_time(lambda: rollout(policy, problems, single_cfg, source))
    t_full, full = median_time(lambda: evaluate(policy, problems, batched_cfg, grids=source))
    t_full_single, _ = median_time(lambda: evaluate(policy, problems, single_cfg, grids=source))

    subset = problems[:args.expert_problems]
    expert_times = []
    for scn in scenes:
        mine = [p for p in subset if p.scene is scn]
        if mine:
            with ExpertPlanner(exact, scn) as planner:
                expert_times += [planner.plan(p.q_start, p.q_goal, seed=0).stats["planning_time"] for p in mine]
    policy_times = [r.solution_time for r in single[:len(subset)]]
    steps = [len(r.trajectory) - 1 for r in batched]
    m = full["metrics"]["all"]
    step_batched = statistics.mean(t for r in batched for t in r.step_times)
    step_single = statistics.mean(t for r in single for t in r.step_times)
    n = len(problems)
    metrics = {"problems": n, "n_e": args.n_e, "steps_mean": statistics.mean(steps),
               "rollout/batched_per_s": n / t_batched, "rollout/single_per_s": n / t_single,
               "rollout/speedup": t_single / t_batched, "evaluate/batched_per_s": n / t_full,
               "evaluate/single_per_s": n / t_full_single, "evaluate/speedup": t_full_single / t_full,
               "step/batched_ms": 1e3 * step_batched, "step/single_ms": 1e3 * step_single,
               "solution/policy_single_s": statistics.mean(policy_times),
               "solution/policy_batched_s": statistics.mean(r.solution_time for r in batched),
               "solution/expert_s": statistics.mean(expert_times),
               "solution/expert_vs_policy": statistics.mean(expert_times) / statistics.mean(policy_times),
               f"{label}/success_rate": m["success_rate"], f"{label}/collision_rate": m["collision_rate"]}
    rows = [[f"rollouts ({n} problems, n_e={args.n_e}, {statistics.mean(steps):.0f} steps avg)",
             f"{n / t_batched:.1f}/s batched", f"{n / t_single:.1f}/s one at a time", f"{t_single / t_batched:.1f}x"],
            ["rollouts + pybullet checks (evaluate)", f"{n / t_full:.1f}/s batched", f"{n / t_full_single:.1f}/s one at a time",
             f"{t_full_single / t_full:.1f}x"],
            ["policy step call", f"{1e3 * step_batched:.2f} ms for B<={n}", f"{1e3 * step_single:.2f} ms for B=1",
             f"{step_single * n / step_batched:.1f}x per problem"],
            [f"solution time, {len(subset)} problems", f"{statistics.mean(policy_times) * 1e3:.1f} ms policy (B=1)",
             f"{statistics.mean(expert_times):.3f} s expert planning",
             f"{statistics.mean(expert_times) / statistics.mean(policy_times):.2f}x"],
            [f"{label} policy on these problems", f"success {m['success_rate']:.0%}",
             f"collision {m['collision_rate']:.0%}", ""]]
    return metrics, [["what", "samp", "baseline", "ratio"], *rows]


@suite
def policy(args) -> tuple[dict, list[list]]:
    """SAMP policy training throughput and per-step inference at several n_e; scene-grouped batches
    (2 scenes per batch of 50) against plain random batches over 8 scenes as the ratio baseline."""
    import resource

    from omegaconf import OmegaConf

    from samp.paths import conf_dir
    from samp.policy.system import PolicySystem
    from samp.robot import load_robot
    from samp.robot_sdf.artifact import describe, net_spec
    from samp.robot_sdf.model import UnifiedHashSDF
    from samp.robot_sdf.samples import link_normalisation
    from samp.scene import generate_scene

    device = torch.device(args.device)
    robot = load_robot(args.robot)
    # An untrained robot SDF of the default architecture: its cost is that of a trained one.
    kwargs = {k: v for k, v in OmegaConf.to_container(OmegaConf.load(conf_dir() / "model" / "robot_sdf_hash.yaml")).items()
              if not k.startswith("_")}
    kwargs["num_links"] = len(robot.link_names)
    net = UnifiedHashSDF(**kwargs)
    centres, scales = link_normalisation(robot, 0.02)
    payload = {"info": describe(robot, net_spec(net, kwargs), "bench", torch.tensor(centres), torch.tensor(scales)),
               "state_dict": net.state_dict()}
    system = PolicySystem(robot=args.robot, robot_sdf_payload=payload).to(device)
    lo, hi = robot.joint_limits.float().T
    g = torch.Generator().manual_seed(0)
    scenes = [generate_scene(["tabletop", "shelf", "cabinet", "blocks"][i % 4], seed=i) for i in range(8)]
    bounds = scenes[0].bounds
    metrics, rows = {}, []
    B = 50
    for n_e in args.anchors:
        system.grids = torch.stack([s.anchor_grid(n_e) for s in scenes]).to(device)
        system.hparams.bounds, system.hparams.n_e = bounds, n_e
        q = (lo + (hi - lo) * torch.rand(B, robot.dof, generator=g)).to(device)
        batch = {"q": q, "q_next": q + 0.01, "q_goal": q.flip(0)}
        opt = torch.optim.AdamW(system.net.parameters(), lr=1e-4)

        def step(scene):
            loss = system._losses({**batch, "scene": scene})["loss"]
            opt.zero_grad()
            loss.backward()
            opt.step()

        grouped = torch.arange(B, device=device) * 2 // B  # 2 scenes
        plain = torch.randint(0, len(scenes), (B,), generator=g).to(device)  # ~8 scenes
        t_grouped = timeit(lambda: step(grouped), device, min_time=0.0, repeats=3)
        t_plain = timeit(lambda: step(plain), device, min_time=0.0, repeats=3)
        system.eval()
        with torch.no_grad():
            features = system.encode(system.grids[:1])
            zero = torch.zeros(1, dtype=torch.long, device=device)
            t_infer = timeit(lambda: system.predict(q[:1], q[1:2], features, zero, bounds), device, min_time=0.0, repeats=5)
        system.train()
        metrics.update({f"n{n_e}/train_samples_per_s": B / t_grouped, f"n{n_e}/train_samples_per_s_random": B / t_plain,
                        f"n{n_e}/grouped_speedup": t_plain / t_grouped, f"n{n_e}/inference_ms": 1e3 * t_infer})
        rows.append([f"train n_e={n_e} (B=50)", f"{B / t_grouped:.0f} samples/s", f"{B / t_plain:.0f} samples/s (random)",
                     f"{t_plain / t_grouped:.2f}x"])
        rows.append([f"  one policy step n_e={n_e}", f"{1e3 * t_infer:.1f} ms", "", ""])
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    metrics["peak_rss_mb"] = peak
    if device.type == "cuda":
        metrics["peak_cuda_mb"] = torch.cuda.max_memory_allocated(device) / 2**20
    rows.append(["peak memory (process RSS)", f"{peak:.0f} MB", "", ""])
    return metrics, [["what", "samp", "baseline", "ratio"], *rows]


@suite
def robot_sdf(args) -> tuple[dict, list[list]]:
    """Table III in one run (`samp.robot_sdf.compare.compare_methods`): the hash-grid SDF and NN-SDF trained
    by the recipe, RDF with N = 8 and N = 24 fitted on the same samples, all evaluated on the same points.
    Ratios are each method's error and time over the hash grid's (above 1: the hash grid is better)."""
    from samp.robot_sdf.compare import compare_methods

    overrides = [f"trainer.accelerator={'gpu' if args.device.startswith('cuda') else 'cpu'}", *args.override]
    report, folder = compare_methods(args.robot, overrides)
    methods = report["methods"]
    ours = next(label for label in methods if "hash" in label.lower() or label.startswith("SAMP"))
    metrics, rows = {"folder": str(folder), "dataset_id": report["dataset_id"]}, []
    keys = [("whole_robot", "mae_all_mm"), ("whole_robot", "mae_near_mm"), ("whole_robot", "mae_far_mm"),
            ("whole_robot", "rmse_all_mm"), ("whole_robot", "rmse_near_mm"), ("whole_robot", "rmse_far_mm")]
    for label, res in methods.items():
        for part, key in keys:
            metrics[f"{label}/{part}/{key}"] = res[part][key]
        metrics[f"{label}/train_time_s"] = res["train_time_s"]
        for b, ms in res["infer_ms"].items():
            metrics[f"{label}/infer_ms_{b}"] = ms
    for part, key in keys:
        base = methods[ours][part][key]
        for label, res in methods.items():
            rows.append([f"{key} ({part}) {label}", f"{base:.2f} mm", f"{res[part][key]:.2f} mm",
                         f"{res[part][key] / base:.2f}x"])
    for label, res in methods.items():
        rows.append([f"train time {label}", f"{methods[ours]['train_time_s']:.0f} s", f"{res['train_time_s']:.0f} s",
                     f"{res['train_time_s'] / methods[ours]['train_time_s']:.2f}x"])
        for b, ms in res["infer_ms"].items():
            rows.append([f"query {b}x{args.points} points {label}", f"{methods[ours]['infer_ms'][b]:.2f} ms",
                         f"{ms:.2f} ms", f"{ms / methods[ours]['infer_ms'][b]:.2f}x"])
    print((Path(folder) / "robot_sdf_table.md").read_text())
    return metrics, [["what", ours, "method", "ratio"], *rows]


@suite
def perception(args) -> tuple[dict, list[list]]:
    """Reconstruction from simulated depth cameras: per-scene time at each n_e (baseline: the exact grid in the
    same run), its error near obstacles, and with --run a trained policy's success on exact vs reconstructed
    grids for the held-out scenes of --dataset."""
    from samp.perception import reconstruct_grid, reconstruction_error
    from samp.robot import load_robot
    from samp.scene import generate_scene
    from samp.sim import World
    from samp.sim.camera import load_camera_set, robot_volume

    robot, cameras = load_robot(args.robot, dtype=torch.float64), load_camera_set(args.camera)
    scenes = [generate_scene(g, seed=i) for i, g in enumerate(["tabletop", "shelf", "cabinet", "blocks"])]
    q = robot.home.numpy()
    t0 = time.perf_counter()
    captured = []
    for scn in scenes:
        with World(robot, scn) as world:
            captured.append(world.capture(cameras, q))
    t_capture = (time.perf_counter() - t0) / len(scenes)
    size = "+".join(sorted({f"{c.width}x{c.height}" for c in cameras.cameras}))
    metrics = {"scenes": len(scenes), "cameras": len(cameras.cameras), "camera_set": cameras.name,
               "unknown": args.unknown, "capture_s_per_scene": t_capture}
    rows = [[f"capture, {len(cameras.cameras)} cameras {size}, per scene", f"{t_capture:.3f} s", "", ""]]
    for n in args.anchors:
        t_rec, t_exact, errors = [], [], []
        for scn, scans in zip(scenes, captured):
            lo, hi = np.asarray(scn.bounds)
            free = robot_volume(robot, q, 0.5 * float(np.linalg.norm((hi - lo) / (n - 1))))
            t0 = time.perf_counter()
            rec = reconstruct_grid(scans, n, scn.bounds, args.unknown, known_free=free)
            t_rec.append(time.perf_counter() - t0)
            t0 = time.perf_counter()
            exact = scn.anchor_grid(n, cache=False)
            t_exact.append(time.perf_counter() - t0)
            errors.append(reconstruction_error(rec.grid, exact))
        rec_s, exact_s = statistics.mean(t_rec), statistics.mean(t_exact)
        mae, mae_all = (statistics.mean(e[k] for e in errors) for k in ("mae_near_mm", "mae_all_mm"))
        metrics.update({f"n{n}/reconstruct_s": rec_s, f"n{n}/exact_grid_s": exact_s, f"n{n}/speed_ratio": exact_s / rec_s,
                        f"n{n}/mae_near_mm": mae, f"n{n}/mae_all_mm": mae_all})
        rows.append([f"reconstruct n_e={n}, per scene", f"{rec_s:.3f} s", f"{exact_s:.3f} s (exact grid)",
                     f"{exact_s / rec_s:.2f}x"])
        rows.append([f"  error n_e={n}: MAE near obstacles / all", f"{mae:.1f} mm", f"{mae_all:.1f} mm", ""])
    if args.run is None:
        metrics["policy/measured"] = False
        rows.append(["policy success, exact vs reconstructed", "not measured: give --run RUN_DIR", "", ""])
        return metrics, [["what", "samp", "baseline", "ratio"], *rows]
    from samp.data import open_dataset
    from samp.eval import dataset_grids, evaluate, load_planner, problems_from_dataset
    from samp.eval.checks import exact_robot
    from samp.perception import ReconstructedGrids

    ds = open_dataset(args.dataset)
    problems = problems_from_dataset(ds, "heldout", args.problems, seed=0)
    policy = load_planner(args.run)
    exact_grids = dataset_grids(ds)
    source = ReconstructedGrids(cameras, exact_robot(policy.robot), exact=exact_grids, unknown=args.unknown)
    on_exact = evaluate(policy, problems, grids=exact_grids)["metrics"]["heldout"]
    on_recon = evaluate(policy, problems, grids=source)["metrics"]["heldout"]
    metrics.update({"policy/measured": True, "policy/dataset": f"{ds.name}@{ds.id}", "policy/problems": len(problems),
                    "policy/n_e": policy.n_e, "policy/mae_near_mm": source.report()["mean"]["mae_near_mm"],
                    **{f"policy/{k}_{which}": m[k] for which, m in (("exact", on_exact), ("reconstructed", on_recon))
                       for k in ("success_rate", "collision_rate", "reach_rate")}})
    for k in ("success_rate", "collision_rate", "reach_rate"):
        rows.append([f"policy {k} ({len(problems)} held-out problems)", f"{on_recon[k]:.1%} reconstructed",
                     f"{on_exact[k]:.1%} exact", f"{on_recon[k] - on_exact[k]:+.1%}"])
    return metrics, [["what", "samp", "baseline", "ratio"], *rows]


def _baseline_planners(args, bounds) -> tuple[dict, set]:
    """name -> planner for the `baselines` suite: the runs in --runs (samp, mpinet, mpnet by their names),
    and untrained networks of the default sizes for those missing; and the names of the untrained ones."""
    from hydra.utils import instantiate
    from omegaconf import OmegaConf

    from samp.eval import load_planner
    from samp.paths import conf_dir
    from samp.policy import SAMPStepPolicy
    from samp.policy.system import PolicySystem
    from samp.robot import load_robot
    from samp.robot_sdf.artifact import describe, net_spec
    from samp.robot_sdf.model import UnifiedHashSDF
    from samp.robot_sdf.samples import link_normalisation
    from samp.train import compose_train_config

    planners = {}
    for run in args.runs:
        planner = load_planner(run)
        planners[planner.name] = planner
    missing = [k for k in ("samp", "mpinet", "mpnet") if k not in planners]
    for kind in missing:
        if kind == "samp":  # an untrained robot SDF of the default architecture costs what a trained one does
            robot = load_robot(args.robot)
            kw = {k: v for k, v in OmegaConf.to_container(OmegaConf.load(conf_dir() / "model" / "robot_sdf_hash.yaml")).items()
                  if not k.startswith("_")}
            net = UnifiedHashSDF(**{**kw, "num_links": len(robot.link_names)})
            centres, scales = link_normalisation(robot, 0.02)
            info = describe(robot, net_spec(net, {**kw, "num_links": len(robot.link_names)}), "bench",
                            torch.tensor(centres), torch.tensor(scales))
            system = PolicySystem(robot=args.robot, robot_sdf_payload={"info": info, "state_dict": net.state_dict()})
        else:
            system = instantiate(compose_train_config([f"+experiment={kind}", f"robot={args.robot}"]).system)
        system.hparams.n_e, system.hparams.bounds = args.n_e, bounds
        system = system.to(torch.device(args.device)).eval()
        planners[kind] = SAMPStepPolicy(system) if kind == "samp" else system.planner()
    return planners, set(missing)


@suite
def baselines(args) -> tuple[dict, list[list]]:
    """Table I's timing columns on CPU: per-step inference and solution time of SAMP, MPiNet, MPNet and
    the OMPL expert rows on the same --baseline-problems problems (two scenes), as ratios to SAMP."""
    from samp.eval import ExpertPlanner, Problem, RolloutConfig, rollout
    from samp.eval.planners import EXPERT_VARIANTS
    from samp.expert import load_expert_config, sample_problems
    from samp.robot import load_robot
    from samp.scene import generate_scene

    exact = load_robot(args.robot, dtype=torch.float64)
    scenes = [generate_scene("tabletop", seed=0), generate_scene("shelf", seed=1)]
    problems, per_scene = [], -(-args.baseline_problems // len(scenes))
    for i, scn in enumerate(scenes):
        drawn = sample_problems(exact, scn, per_scene + 5, seed=i, cfg=load_expert_config())
        problems += [Problem(scn, p.q_start, p.q_goal, split="train", name=f"bench{i}/{k}", robot=exact.name)
                     for k, p in enumerate(drawn) if p.q_goal is not None][:per_scene]
    planners, untrained = _baseline_planners(args, scenes[0].bounds)
    planners["expert"] = ExpertPlanner("plan", exact)
    for name, overrides in EXPERT_VARIANTS.items():
        planners[name] = ExpertPlanner("plan", exact, load_expert_config(None, **overrides), name=name)
    step, solve, solved = {}, {}, {}
    for name, planner in planners.items():
        if hasattr(planner, "step"):  # a step policy: rollouts one problem at a time, timed by the engine
            results = rollout(planner, problems, RolloutConfig(batch_size=1), lambda p, n: p.scene.anchor_grid(n))
            step[name] = statistics.mean(t for r in results for t in r.step_times)
            solve[name] = statistics.mean(r.solution_time for r in results)
            solved[name] = statistics.mean(r.termination == "reached" for r in results)
            continue
        if name == "mpnet":  # one network call (B=1); whole plans only with a trained network
            with torch.no_grad():
                code = planner.system.net.encode(scenes[0].anchor_grid(planner.n_e)[None].to(planner.system.device))
                step[name] = timeit(lambda: planner._step(problems[0].q_start, problems[0].q_goal, code),
                                    torch.device(args.device), min_time=0.05, repeats=3)
            if name in untrained:
                continue
        answers = [planner.plan(p) for p in problems]
        solve[name] = statistics.mean(a.solution_time for a in answers)
        solved[name] = statistics.mean(a.trajectory is not None for a in answers)
    metrics, rows = {"problems": len(problems), "n_e": args.n_e, "untrained": sorted(untrained)}, []
    for name in planners:
        s, t, ok = step.get(name), solve.get(name), solved.get(name)
        metrics.update({f"{name}/{k}": v for k, v in (("step_ms", s and 1e3 * s), ("solution_s", t), ("solved", ok),
                        ("step_vs_samp", s and s / step["samp"]), ("solution_vs_samp", t and t / solve["samp"]))
                        if v is not None})
        cells = ("-",) * 2 if s is None else (f"{1e3 * s:.2f}", f"{s / step['samp']:.2f}x")
        cells += ("-",) * 2 if t is None else (f"{t:.3f}", f"{t / solve['samp']:.2f}x")
        rows.append([name + (" (untrained)" if name in untrained else ""), *cells, "-" if ok is None else f"{ok:.0%}"])
    if untrained:  # rollouts of an untrained policy end at max_steps or a stall, not at the goal
        print(f"note: {', '.join(sorted(untrained))} untrained (default sizes; pass trained run folders with --runs): "
              "their step times hold, their solution times and solved shares do not; untrained MPNet does not plan")
    return metrics, [["planner", "step [ms]", "step vs samp", "solution [s]", "solution vs samp", "reached/planned"], *rows]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("suite", choices=sorted(SUITES))
    ap.add_argument("--out", type=Path, help="write the JSON report here")
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    ap.add_argument("--robot", default="panda")
    ap.add_argument("--batch", type=int, nargs="+", default=[1, 50, 1024])
    ap.add_argument("--anchors", type=int, nargs="+", default=[40, 100, 160])
    ap.add_argument("--configs", type=int, default=500, help="configurations for World.in_collision")
    ap.add_argument("--workers", type=int, default=2, help="data: worker processes for expert generation")
    ap.add_argument("--scenes", type=int, default=4, help="data: scenes generated (one held out)")
    ap.add_argument("--trajectories", type=int, default=25, help="data: problems per scene")
    ap.add_argument("--problems", type=int, default=100, help="eval: problems rolled out (over two scenes)")
    ap.add_argument("--n-e", type=int, default=100, help="eval: anchors per axis of the grids handed to the policy")
    ap.add_argument("--expert-problems", type=int, default=10, help="eval: problems the expert plans afresh")
    ap.add_argument("--policy-run", help="eval: a trained policy's run folder (default: the straight-line policy)")
    ap.add_argument("--override", nargs="*", default=[], help="robot_sdf: overrides for both network runs, "
                    "e.g. robot_sdf_samples=tiny trainer.max_steps=200")
    ap.add_argument("--points", type=int, default=1024, help="robot_sdf: robot points per configuration (label only)")
    ap.add_argument("--camera", default="default", help="perception: camera set (conf/camera/NAME.yaml or a YAML path)")
    ap.add_argument("--unknown", default="free", choices=["free", "occupied"],
                    help="perception: what space no camera saw becomes")
    ap.add_argument("--run", help="perception: a trained policy's run folder, to compare exact and reconstructed grids")
    ap.add_argument("--dataset", default="standard", help="perception: the dataset whose held-out scenes --run is "
                    "evaluated on")
    ap.add_argument("--runs", nargs="*", default=[], help="baselines: trained run folders (samp, mpinet, mpnet); "
                    "those missing are timed as untrained networks of the default sizes")
    ap.add_argument("--baseline-problems", type=int, default=6, help="baselines: problems each planner solves")
    args = ap.parse_args(argv)
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        ap.error("--device cuda was asked for but torch sees no CUDA device")
    metrics, table = SUITES[args.suite](args)
    widths = [max(len(str(r[i])) for r in table) for i in range(len(table[0]))]
    print(f"suite {args.suite} ({args.robot}, {args.device}); ratios are baseline time / samp time")
    for r in table:
        print("  ".join(str(c).rjust(w) for c, w in zip(r, widths)))
    report = {"suite": args.suite, "metrics": metrics, "machine": machine(torch.device(args.device)),
              "config": {k: v for k, v in vars(args).items() if k not in ("out", "suite")}}
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2))
        print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
