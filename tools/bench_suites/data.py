"""`data` suite: expert trajectories per second on --workers processes and the planner's success rate per scene
generator; open_dataset (decoded waypoints per second) and grid decoding against the same arrays read from a .npz
file."""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from .common import HEADER, timeit


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--workers", type=int, default=2, help="data: worker processes for expert generation")
    ap.add_argument("--scenes", type=int, default=4, help="data: scenes generated (one of them val)")
    ap.add_argument("--trajectories", type=int, default=25, help="data: problems per scene")


def _generation(args, spec: dict, m: dict, ds, t_gen: float) -> tuple[dict, list[list]]:
    """Problems per second of the generation that took `t_gen`, and the planner's success per generator."""
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
    return metrics, rows


def _reading(folder: Path, root: Path, m: dict, ds) -> tuple[dict, list[list]]:
    """Decoding the dataset (waypoints, and the n_e = 100 grids per scene) against the same arrays in a .npz
    file written under `root`."""
    from samp.data import open_dataset
    from samp.data.mcap_io import read_scene_file

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
    metrics = {"read/samples": samples, "read/mcap_samples_per_s": samples / t_mcap,
               "read/npz_samples_per_s": samples / t_npz, "read/mcap_vs_npz": t_npz / t_mcap,
               "read/grid100_mcap_s_per_scene": t_grid / len(files),
               "read/grid100_npz_s_per_scene": max(t_grid_npz, 0.0) / len(files),
               "dataset/bytes": sum(f.stat().st_size for f in files)}
    rows = [[f"open_dataset ({samples} waypoints)", f"{samples / t_mcap:,.0f} samples/s",
             f"{samples / t_npz:,.0f} samples/s (npz)", f"{t_npz / t_mcap:.3f}x"],
            ["grid n_e=100, per scene", f"{1e3 * t_grid / len(files):.1f} ms", f"{1e3 * max(t_grid_npz, 0) / len(files):.1f} ms (npz)",
             f"{max(t_grid_npz, 1e-9) / t_grid:.2f}x"]]
    return metrics, rows


def run(args) -> tuple[dict, list[list]]:
    """Expert generation on `--workers` processes, and decoding the dataset against the same arrays in .npz."""
    from samp.data import generate, open_dataset, read_manifest

    spec = {"name": "bench", "robot": args.robot, "seed": 0, "train_scenes": args.scenes - 1, "val_scenes": 1,
            "trajectories_per_scene": args.trajectories, "eval_problems_per_scene": 0,  # demonstrations only
            "generators": ["tabletop", "shelf", "cabinet", "blocks"], "resolutions": [40, 100]}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        folder = generate(spec, workers=args.workers, root=root, progress=True)
        t_gen = time.perf_counter() - t0
        m = read_manifest(folder)
        ds = open_dataset(folder)
        metrics, rows = _generation(args, spec, m, ds, t_gen)
        read_metrics, read_rows = _reading(folder, root, m, ds)
    metrics.update(read_metrics)
    return metrics, [HEADER, *rows, *read_rows]
