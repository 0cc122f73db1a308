"""`robot_sdf` suite: the paper's Table III in one run: the hash-grid robot SDF, NN-SDF, RDF (N = 8) and RDF
(N = 24) trained or fitted on the same samples and evaluated on the same points (minutes on CPU); ratios against
the hash grid."""

from __future__ import annotations

import argparse
from pathlib import Path

# The error columns of Table III, as (part of the report, key).
KEYS = [("whole_robot", "mae_all_mm"), ("whole_robot", "mae_near_mm"), ("whole_robot", "mae_far_mm"),
        ("whole_robot", "rmse_all_mm"), ("whole_robot", "rmse_near_mm"), ("whole_robot", "rmse_far_mm")]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--override", nargs="*", default=[], help="robot_sdf: overrides for both network runs, "
                    "e.g. robot_sdf_samples=tiny trainer.max_steps=200")
    ap.add_argument("--points", type=int, default=1024, help="robot_sdf: robot points per configuration (label only)")
    ap.add_argument("--sdf-eval", default="default", help="robot_sdf: the accuracy evaluation's sizes, "
                    "conf/robot_sdf_eval/NAME.yaml (tiny: a quick check, not Table III)")


def _rows(methods: dict, ours: str, points: int) -> list[list]:
    """Each method's errors, train time and query times next to the hash grid's (`ours`), as ratios."""
    rows = []
    for part, key in KEYS:
        base = methods[ours][part][key]
        for label, res in methods.items():
            rows.append([f"{key} ({part}) {label}", f"{base:.2f} mm", f"{res[part][key]:.2f} mm",
                         f"{res[part][key] / base:.2f}x"])
    for label, res in methods.items():
        rows.append([f"train time {label}", f"{methods[ours]['train_time_s']:.0f} s", f"{res['train_time_s']:.0f} s",
                     f"{res['train_time_s'] / methods[ours]['train_time_s']:.2f}x"])
        for b, ms in res["infer_ms"].items():
            rows.append([f"query {b}x{points} points {label}", f"{methods[ours]['infer_ms'][b]:.2f} ms",
                         f"{ms:.2f} ms", f"{ms / methods[ours]['infer_ms'][b]:.2f}x"])
    return rows


def run(args) -> tuple[dict, list[list]]:
    """Table III in one run (`samp.train.robot_sdf_compare.compare_methods`): the hash-grid SDF and NN-SDF trained
    by the recipe, RDF with N = 8 and N = 24 fitted on the same samples, all evaluated on the same points.
    Ratios are each method's error and time over the hash grid's (above 1: the hash grid is better)."""
    from samp.train.robot_sdf_compare import compare_methods

    overrides = [f"trainer.accelerator={'gpu' if args.device.startswith('cuda') else 'cpu'}", *args.override]
    from omegaconf import OmegaConf

    from samp.cli import compose

    evaluation = OmegaConf.to_container(compose("train", [f"+robot_sdf_eval={args.sdf_eval}"]).robot_sdf_eval)
    report, folder = compare_methods(args.robot, overrides, evaluation=evaluation)
    methods = report["methods"]
    ours = next(label for label in methods if "hash" in label.lower() or label.startswith("SAMP"))
    metrics = {"folder": str(folder), "dataset_id": report["dataset_id"]}
    for label, res in methods.items():
        for part, key in KEYS:
            metrics[f"{label}/{part}/{key}"] = res[part][key]
        metrics[f"{label}/train_time_s"] = res["train_time_s"]
        for b, ms in res["infer_ms"].items():
            metrics[f"{label}/infer_ms_{b}"] = ms
    print((Path(folder) / "robot_sdf_table.md").read_text())
    return metrics, [["what", ours, "method", "ratio"], *_rows(methods, ours, args.points)]
