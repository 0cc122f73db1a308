"""`perception` suite: depth-camera capture and anchor-grid reconstruction per scene at n_e in --anchors (four
scenes, --camera set, --unknown policy), against the exact scene.anchor_grid as the baseline, with the
reconstruction error near obstacles; with --run, the policy's success rate on exact vs reconstructed grids for
--problems validation-scene problems of --dataset.

Adds --camera, --unknown, --run and --dataset; reads --anchors (added by the scene suite) and --problems (added
by the eval suite)."""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
import torch

from .common import HEADER


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--camera", default="default", help="perception: camera set (conf/camera/NAME.yaml or a YAML path)")
    ap.add_argument("--unknown", default="free", choices=["free", "occupied"],
                    help="perception: what space no camera saw becomes")
    ap.add_argument("--run", help="perception: a trained policy's run folder, to compare exact and reconstructed grids")
    ap.add_argument("--dataset", default="standard", help="perception: the dataset whose held-out scenes --run is "
                    "evaluated on")


def _capture(robot, cameras, scenes: list, q: np.ndarray) -> tuple[list, float]:
    """Every scene's scans with the robot at `q`, and the seconds per scene."""
    from samp.sim import World

    t0 = time.perf_counter()
    captured = []
    for scn in scenes:
        with World(robot, scn) as world:
            captured.append(world.capture(cameras, q))
    return captured, (time.perf_counter() - t0) / len(scenes)


def _reconstruction(robot, q: np.ndarray, scenes: list, captured: list, n: int,
                    unknown: str) -> tuple[dict, list[list]]:
    """Reconstruction at n_e = n against the exact grid: mean seconds per scene of each, and the errors."""
    from samp.perception import reconstruct_grid, reconstruction_error
    from samp.sim.camera import robot_volume

    t_rec, t_exact, errors = [], [], []
    for scn, scans in zip(scenes, captured):
        lo, hi = np.asarray(scn.bounds)
        free = robot_volume(robot, q, 0.5 * float(np.linalg.norm((hi - lo) / (n - 1))))
        t0 = time.perf_counter()
        rec = reconstruct_grid(scans, n, scn.bounds, unknown, known_free=free)
        t_rec.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        exact = scn.anchor_grid(n, cache=False)
        t_exact.append(time.perf_counter() - t0)
        errors.append(reconstruction_error(rec.grid, exact))
    rec_s, exact_s = statistics.mean(t_rec), statistics.mean(t_exact)
    mae, mae_all = (statistics.mean(e[k] for e in errors) for k in ("mae_near_mm", "mae_all_mm"))
    metrics = {f"n{n}/reconstruct_s": rec_s, f"n{n}/exact_grid_s": exact_s, f"n{n}/speed_ratio": exact_s / rec_s,
               f"n{n}/mae_near_mm": mae, f"n{n}/mae_all_mm": mae_all}
    rows = [[f"reconstruct n_e={n}, per scene", f"{rec_s:.3f} s", f"{exact_s:.3f} s (exact grid)",
             f"{exact_s / rec_s:.2f}x"],
            [f"  error n_e={n}: MAE near obstacles / all", f"{mae:.1f} mm", f"{mae_all:.1f} mm", ""]]
    return metrics, rows


def _policy_success(args, cameras) -> tuple[dict, list[list]]:
    """--run's policy on --problems validation-scene problems of --dataset, on exact and on reconstructed grids."""
    from samp.data import open_dataset
    from samp.eval import dataset_grids, evaluate, load_planner, problems_from_dataset
    from samp.eval.checks import exact_robot
    from samp.perception import ReconstructedGrids

    ds = open_dataset(args.dataset)
    problems = problems_from_dataset(ds, "val", args.problems, seed=0)
    policy = load_planner(args.run)
    exact_grids = dataset_grids(ds)
    source = ReconstructedGrids(cameras, exact_robot(policy.robot), exact=exact_grids, unknown=args.unknown)
    on_exact = evaluate(policy, problems, grids=exact_grids)["metrics"]["val"]
    on_recon = evaluate(policy, problems, grids=source)["metrics"]["val"]
    metrics = {"policy/measured": True, "policy/dataset": f"{ds.name}@{ds.id}", "policy/problems": len(problems),
               "policy/n_e": policy.n_e, "policy/mae_near_mm": source.report()["mean"]["mae_near_mm"],
               **{f"policy/{k}_{which}": m[k] for which, m in (("exact", on_exact), ("reconstructed", on_recon))
                  for k in ("success_rate", "collision_rate", "reach_rate")}}
    rows = [[f"policy {k} ({len(problems)} validation-scene problems)", f"{on_recon[k]:.1%} reconstructed",
             f"{on_exact[k]:.1%} exact", f"{on_recon[k] - on_exact[k]:+.1%}"]
            for k in ("success_rate", "collision_rate", "reach_rate")]
    return metrics, rows


def run(args) -> tuple[dict, list[list]]:
    """Reconstruction from simulated depth cameras: per-scene time at each n_e (baseline: the exact grid in the
    same run), its error near obstacles, and with --run a trained policy's success on exact vs reconstructed
    grids for the validation scenes of --dataset."""
    from samp.robot import load_robot
    from samp.scene import generate_scene
    from samp.sim.camera import load_camera_set

    robot, cameras = load_robot(args.robot, dtype=torch.float64), load_camera_set(args.camera)
    scenes = [generate_scene(g, seed=i) for i, g in enumerate(["tabletop", "shelf", "cabinet", "blocks"])]
    q = robot.home.numpy()
    captured, t_capture = _capture(robot, cameras, scenes, q)
    size = "+".join(sorted({f"{c.width}x{c.height}" for c in cameras.cameras}))
    metrics = {"scenes": len(scenes), "cameras": len(cameras.cameras), "camera_set": cameras.name,
               "unknown": args.unknown, "capture_s_per_scene": t_capture}
    rows = [[f"capture, {len(cameras.cameras)} cameras {size}, per scene", f"{t_capture:.3f} s", "", ""]]
    for n in args.anchors:
        n_metrics, n_rows = _reconstruction(robot, q, scenes, captured, n, args.unknown)
        metrics.update(n_metrics)
        rows += n_rows
    if args.run is None:
        metrics["policy/measured"] = False
        rows.append(["policy success, exact vs reconstructed", "not measured: give --run RUN_DIR", "", ""])
        return metrics, [HEADER, *rows]
    policy_metrics, policy_rows = _policy_success(args, cameras)
    metrics.update(policy_metrics)
    return metrics, [HEADER, *rows, *policy_rows]
