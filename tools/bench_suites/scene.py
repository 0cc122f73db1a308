"""`scene` suite: anchor grids at n_e in --anchors and World.in_collision on a 20-obstacle scene; baselines: the
same distances one point at a time (timed on a sample, scaled to the grid), and a pairwise pybullet check of every
link part against every obstacle without broadphase.

Adds --anchors (also read by the policy and perception suites) and --configs."""

from __future__ import annotations

import argparse
import time

import numpy as np
import torch

from .common import timeit


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--anchors", type=int, nargs="+", default=[40, 100, 160])
    ap.add_argument("--configs", type=int, default=500, help="configurations for World.in_collision")


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

    from samp.robot.bodies import MESH_MARGIN

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


def run(args) -> tuple[dict, list[list]]:
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
