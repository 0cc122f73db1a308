"""`policy` suite: SAMP policy training samples per second (scene-grouped batches vs random batches) and one policy
step, at each --anchors n_e (the option is added by the scene suite); peak memory."""

from __future__ import annotations

import argparse

import torch

from samp.data.binding import DatasetBinding

from .common import HEADER, timeit, untrained_policy_system

B = 50  # training batch size


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """None of its own: --anchors comes from the scene suite, --robot and --device from common."""


def _time_n_e(system, robot, scenes: list, n_e: int, g: torch.Generator, device: torch.device) -> tuple[float, ...]:
    """(grouped, random) seconds per training step of B samples and seconds per policy step (B = 1), at n_e."""
    lo, hi = robot.joint_limits.float().T
    bounds = scenes[0].bounds
    grids = torch.stack([s.anchor_grid(n_e) for s in scenes])
    system.bind(DatasetBinding(robot.name, robot.asset_hash, "bench", n_e, bounds, grids))
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
    return t_grouped, t_plain, t_infer


def run(args) -> tuple[dict, list[list]]:
    """SAMP policy training throughput and per-step inference at several n_e; scene-grouped batches
    (2 scenes per batch of 50) against plain random batches over 8 scenes as the ratio baseline."""
    import resource

    from samp.robot import load_robot
    from samp.scene import generate_scene

    device = torch.device(args.device)
    robot = load_robot(args.robot)
    # An untrained robot SDF of the default architecture: its cost is that of a trained one.
    system = untrained_policy_system(robot, args.robot).to(device)
    g = torch.Generator().manual_seed(0)
    scenes = [generate_scene(["tabletop", "shelf", "cabinet", "blocks"][i % 4], seed=i) for i in range(8)]
    metrics, rows = {}, []
    for n_e in args.anchors:
        t_grouped, t_plain, t_infer = _time_n_e(system, robot, scenes, n_e, g, device)
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
    return metrics, [HEADER, *rows]
