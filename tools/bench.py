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
    paper   a dry run of the paper-scale recipes (--experiments, default samp_paper samp_paper_ours): their
            composed settings, a training step measured here at n_e = 160 and B = 50 (--steps), the run's
            expected wall time from it beside the paper's own GPU figure, the step's memory, and the disk of
            the `paper` dataset, scaled from small datasets generated here
"""

# A dispatcher: each suite is a module of bench_suites/ (add_arguments, run); bench_suites/common.py holds the
# shared options, timing, table and JSON report.

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import torch

# bench_suites/ sits beside this file; put it on the path however this file is run (as a script it already is).
if str(Path(__file__).resolve().parent) not in sys.path:
    sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_suites import SUITES, common  # noqa: E402 (after the path setup above)


def build_parser() -> argparse.ArgumentParser:
    """One flat parser: the suite, the shared options, then each suite's own options in definition order."""
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("suite", choices=sorted(SUITES))
    common.add_arguments(ap)
    for module in SUITES.values():
        module.add_arguments(ap)
    return ap


def main(argv=None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.device.startswith("cuda") and not torch.cuda.is_available():
        ap.error("--device cuda was asked for but torch sees no CUDA device")
    metrics, table = SUITES[args.suite].run(args)
    common.print_table(args, table)
    common.write_report(args, metrics)
    return 0


if __name__ == "__main__":
    sys.exit(main())
