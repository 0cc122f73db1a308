"""`data` suite: expert generation on --workers processes against a baseline checkout of samp measured in the same
run (trajectories per second, with the planner's success, path length and minimum clearance beside the rate), the
per-stage breakdown of the generation, the expected time of the `standard` and `paper` specs, and open_dataset
(decoded waypoints per second) and grid decoding against the same arrays read from a .npz file."""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch

from .common import HEADER, timeit

REPO = Path(__file__).resolve().parents[2]
# Run in a fresh interpreter with PYTHONPATH at a source tree: generation as a user's command pays for it, process
# start-up included. Prints the wall time and the dataset folder as one JSON line.
GENERATE = ("import json, sys, time; t0 = time.perf_counter(); from samp.data import generate; "
            "spec, workers, root = json.loads(sys.argv[1]), int(sys.argv[2]), sys.argv[3]; "
            "folder = generate(spec, workers=workers, root=root, progress=False); "
            "print(json.dumps({'wall_s': time.perf_counter() - t0, 'folder': str(folder)}))")
# What a worker loads before its first scene (torch, the scene files' writer, the planner, the robot).
STARTUP = ("import time; t0 = time.perf_counter(); import torch; import samp.data.generation as g; "
           "import samp.data.mcap_io, samp.expert.planner; g._robot('{robot}'); print(time.perf_counter() - t0)")


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--workers", type=int, default=2, help="data: worker processes for expert generation")
    ap.add_argument("--scenes", type=int, default=4, help="data: scenes generated (one of them val)")
    ap.add_argument("--trajectories", type=int, default=25, help="data: problems per scene")
    ap.add_argument("--baseline-src", type=Path, default=None,
                    help="data, policy: a checkout of samp to compare with (data's default: --baseline-rev in a "
                    "temporary git worktree; policy: the --policy-run step at B = 1, and with --robot-sdf the training step)")
    ap.add_argument("--baseline-rev", default="47fc6b1",
                    help="data: the commit measured as the baseline when --baseline-src is not given ('none': skip it)")
    ap.add_argument("--detour-share", type=float, default=None,
                    help="data: also time the current code with this detour_share (default: the standard spec's)")


def _spec(args, detour_share: float | None = None) -> dict:
    spec = {"name": "bench", "robot": args.robot, "seed": 0, "train_scenes": args.scenes - 1, "val_scenes": 1,
            "trajectories_per_scene": args.trajectories, "eval_problems_per_scene": 0,  # demonstrations only
            "generators": ["tabletop", "shelf", "cabinet", "blocks"], "resolutions": [40, 100]}
    return spec if detour_share is None else {**spec, "name": "bench_detours", "detour_share": detour_share}


def _run(src: Path, spec: dict, workers: int, root: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", GENERATE, json.dumps(spec), str(workers), str(root)], cwd=src, env=env,
                         capture_output=True, text=True, check=False)
    if out.returncode != 0:
        raise RuntimeError(f"generation in {src} failed:\n{out.stderr[-3000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _startup(src: Path, robot: str) -> float:
    """Seconds a fresh worker process spends importing samp and loading the robot, before its first scene."""
    env = {**os.environ, "PYTHONPATH": str(src), "OMP_NUM_THREADS": "1"}
    out = subprocess.run([sys.executable, "-c", STARTUP.format(robot=robot)], cwd=src, env=env, capture_output=True,
                         text=True, check=True)
    return float(out.stdout.strip().splitlines()[-1])


def _quality(folder: Path, robot) -> dict:
    """What the data is, measured by this checkout whichever code made it: success, path lengths, clearance, and
    the share of problems the expert solved with the straight motion."""
    from samp.data import open_dataset
    from samp.expert.trajectory import joint_path_length
    from samp.sim import World

    ds = open_dataset(folder)
    posed = [e for e in ds.episodes if e["goal"] is not None]
    solved = [e for e in posed if e["success"]]
    clearance = []  # per trajectory: the smallest obstacle distance over its waypoints
    for i, scene in enumerate(ds.scenes):
        with World(robot, scene) as world:
            for traj in ds.trajectories[ds.traj_scene == i].numpy():
                clearance.append(float(world.min_distance(traj).min()))
    lengths = [joint_path_length(t) for t in ds.trajectories.numpy()]
    return {"problems": len(ds.episodes), "trajectories": len(ds), "success": len(solved) / max(1, len(posed)),
            "joint_path_length": float(np.mean(lengths)) if lengths else float("nan"),
            "ee_path_length": float(np.mean([e["stats"]["ee_path_length"] for e in solved])) if solved else float("nan"),
            "min_clearance_mean": float(np.mean(clearance)) if clearance else float("nan"),
            "min_clearance_min": float(np.min(clearance)) if clearance else float("nan"),
            "direct": sum(bool(e["stats"].get("direct")) for e in solved) / max(1, len(solved))}


def _same_files(a: Path, b: Path) -> bool:
    """Two dataset folders hold the same id (folder name) and byte-identical MCAP files."""
    names = sorted(f.name for f in a.glob("*.mcap"))
    return a.name == b.name and names == sorted(f.name for f in b.glob("*.mcap")) and all(
        (a / n).read_bytes() == (b / n).read_bytes() for n in names)


PROBLEMS = "problems (goal and start sampling, batched IK, detour choice)"
SOLVE, SIMPLIFY = "planning: OMPL solve", "planning: simplification and smoothing"
CHECKS = "planning: straight-line check, resampling, dense check, path lengths"
GRIDS, WRITE, REST = "anchor grids", "MCAP writing", "rest: scene set-up, scheduling, merge"
PER_PROBLEM, PER_SCENE = (PROBLEMS, SOLVE, SIMPLIFY, CHECKS, WRITE), (GRIDS, REST)  # how each stage scales


def _breakdown(manifest: dict, wall: float, workers: int, startup: float) -> dict:
    """Seconds per stage summed over the scenes (the workers' time, so they add up to about workers x wall)."""
    scenes = manifest["scenes"]
    total = lambda key: float(sum(sum(s.get(key, [])) for s in scenes))  # noqa: E731
    stage = lambda key: float(sum(s.get("stage_time", {}).get(key, 0.0) for s in scenes))  # noqa: E731
    planning, solve, simplify = total("planning_time"), total("solve_time"), total("simplify_time")
    out = {PROBLEMS: stage("problems"), SOLVE: solve, SIMPLIFY: simplify, CHECKS: planning - solve - simplify,
           GRIDS: stage("grids"), WRITE: stage("write"),
           f"process start-up (import, robot), x{workers} workers": startup * workers}
    out[REST] = max(0.0, wall * workers - sum(out.values()))
    return out


def _estimate(spec_name: str, breakdown: dict, problems: int, scenes: int, cores: int, startup: float) -> float:
    """Seconds to generate conf/dataset/<spec_name>.yaml on `cores` workers: the workers' start-up, then the
    measured worker seconds per problem (sampling, planning, writing) and per scene (grids, set-up, and the
    small run's scheduling and merge, so on the safe side) scaled to the spec and shared among the cores."""
    from samp.data import load_spec

    spec = load_spec(spec_name)
    per_problem = sum(breakdown[k] for k in PER_PROBLEM) / problems
    per_scene = sum(breakdown[k] for k in PER_SCENE) / scenes
    count = sum(j.trajectories + j.eval_problems for j in spec.scene_jobs())
    return startup + (count * per_problem + spec.num_scenes * per_scene) / min(cores, spec.num_scenes)


def _generation(args, root: Path) -> tuple[dict, list[list], Path]:
    from samp.data import load_spec, read_manifest
    from samp.robot import load_robot

    robot = load_robot(args.robot, dtype=torch.float64)
    base, worktree = args.baseline_src, None
    if base is None and str(args.baseline_rev).lower() != "none":
        worktree = root / "baseline_src"
        subprocess.run(["git", "worktree", "add", "--detach", str(worktree), args.baseline_rev], cwd=REPO, check=True,
                       capture_output=True)
        base = worktree
    try:
        runs = {}
        for label, src, spec in (("baseline", base, _spec(args)), ("samp", REPO, _spec(args))):
            if src is not None:
                print(f"data: generating with {label} ({src}) ...", flush=True)
                runs[label] = _run(src, spec, args.workers, root / label)
                runs[label]["startup_s"] = _startup(src, args.robot)
        share = load_spec("standard").detour_share if args.detour_share is None else args.detour_share
        todo = (("baseline_detours", "baseline", base), ("detours", "samp", REPO)) if share > 0 else ()
        for label, code, src in todo:  # a baseline from before detour_share cannot generate the detour spec
            if src is not None and "detour_share" in (src / "samp" / "data" / "spec.py").read_text():
                print(f"data: generating with {code}, detour_share {share} ...", flush=True)
                runs[label] = _run(src, _spec(args, share), args.workers, root / label)
                runs[label]["startup_s"] = runs[code]["startup_s"]
    finally:
        if worktree is not None:
            subprocess.run(["git", "worktree", "remove", "--force", str(worktree)], cwd=REPO, capture_output=True)
    metrics, rows = {"generate/workers": args.workers}, []
    for label, run in runs.items():
        q = _quality(Path(run["folder"]), robot)
        run.update(q, traj_per_s=q["trajectories"] / run["wall_s"], problems_per_s=q["problems"] / run["wall_s"])
        metrics.update({f"{label}/{k}": v for k, v in run.items() if k != "folder"})
    cur, old = runs["samp"], runs.get("baseline")
    ratio = lambda key: f"{cur[key] / old[key]:.2f}x" if old else ""  # noqa: E731
    cell = lambda run, key, fmt: "" if run is None else format(run[key], fmt)  # noqa: E731
    rows += [[f"expert generation, {args.workers} workers, {cur['problems']} problems", f"{cur['traj_per_s']:.2f} traj/s",
              cell(old, "traj_per_s", ".2f") + (" traj/s" if old else ""), ratio("traj_per_s")],
             ["  wall time (s)", f"{cur['wall_s']:.1f}", cell(old, "wall_s", ".1f"), ""],
             ["  planner success (problems with a goal)", f"{cur['success']:.1%}", cell(old, "success", ".1%"), ""],
             ["  joint path length, mean (rad)", f"{cur['joint_path_length']:.3f}", cell(old, "joint_path_length", ".3f"), ""],
             ["  ee path length, mean (m)", f"{cur['ee_path_length']:.3f}", cell(old, "ee_path_length", ".3f"), ""],
             ["  min clearance per trajectory, mean (mm)", f"{1e3 * cur['min_clearance_mean']:.1f}",
              "" if old is None else f"{1e3 * old['min_clearance_mean']:.1f}", ""],
             ["  min clearance, worst trajectory (mm)", f"{1e3 * cur['min_clearance_min']:.1f}",
              "" if old is None else f"{1e3 * old['min_clearance_min']:.1f}", ""],
             ["  solved by the straight motion", f"{cur['direct']:.0%}", cell(old, "direct", ".0%"), ""]]
    if "detours" in runs:
        d, od = runs["detours"], runs.get("baseline_detours")
        rows += [[f"  with detour_share {share}", f"{d['traj_per_s']:.2f} traj/s", cell(od, "traj_per_s", ".2f") +
                  (" traj/s" if od else ""), f"{d['traj_per_s'] / od['traj_per_s']:.2f}x" if od else ""],
                 ["    solved by the straight motion", f"{d['direct']:.0%}", cell(od, "direct", ".0%"), ""],
                 ["    joint path length, mean (rad)", f"{d['joint_path_length']:.3f}",
                  cell(od, "joint_path_length", ".3f"), ""],
                 ["    min clearance per trajectory, mean (mm)", f"{1e3 * d['min_clearance_mean']:.1f}",
                  "" if od is None else f"{1e3 * od['min_clearance_mean']:.1f}", ""]]
    pairs = [(a, b) for a, b in (("samp", "baseline"), ("detours", "baseline_detours")) if b in runs]
    if pairs:  # same spec, same seed: the same dataset, byte for byte, whichever code made it
        same = all(_same_files(Path(runs[a]["folder"]), Path(runs[b]["folder"])) for a, b in pairs)
        metrics["generate/same_files_as_baseline"] = same
        rows.append(["  same dataset ids and files as the baseline", "yes" if same else "NO", "", ""])
    main = "detours" if "detours" in runs else "samp"  # the breakdown of the standard spec's detour share
    wall = runs[main]["wall_s"]
    breakdown = _breakdown(read_manifest(Path(runs[main]["folder"])), wall, args.workers, runs[main]["startup_s"])
    other = "baseline_detours" if main == "detours" else "baseline"
    before = (_breakdown(read_manifest(Path(runs[other]["folder"])), runs[other]["wall_s"], args.workers,
                         runs[other]["startup_s"]) if other in runs else {})
    rows.append([f"breakdown of the {main} run (worker seconds, {args.workers} x {wall:.1f} s wall; baseline's beside)",
                 "", "", ""])
    for stage, seconds in breakdown.items():
        metrics[f"breakdown/{stage}"] = seconds
        rows.append([f"  {stage}", f"{seconds:.1f} s ({seconds / max(1e-9, args.workers * wall):.0%})",
                     f"{before[stage]:.1f} s" if stage in before else "", ""])
    measured = runs[main]  # the run with the standard spec's detour share
    for name in ("standard", "paper"):
        for cores in (2, 8, 32):
            eta = _estimate(name, breakdown, measured["problems"], args.scenes, cores, cur["startup_s"])
            metrics[f"estimate/{name}_{cores}_cores_s"] = eta
            rows.append([f"expected time, {name} spec, {cores} cores", f"{eta / 60:.1f} min", "", ""])
    return metrics, rows, Path(cur["folder"])


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
    """Generation against the baseline with its breakdown and estimates, then decoding against .npz."""
    from samp.data import open_dataset, read_manifest

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        t0 = time.perf_counter()
        metrics, rows, folder = _generation(args, root)
        metrics["bench/s"] = time.perf_counter() - t0
        read_metrics, read_rows = _reading(folder, root, read_manifest(folder), open_dataset(folder))
    metrics.update(read_metrics)
    return metrics, [HEADER, *rows, *read_rows]
