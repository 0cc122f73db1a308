"""The robot SDF evaluation of the paper's Table III: accuracy against trimesh, training and inference time.

Two held-out point sets, drawn with a fixed seed (`SDFEvalConfig.seed`) so that figures compare across
versions and methods, with ground truth from trimesh (`samples.link_signed_distance`):

- per link: half near the surface (area-weighted surface samples moved along random unit directions
  by Gaussian noise, an equal share at each of `noise` = 2.5, 10, 30 mm), half uniform in the link box;
  the method's link distance (box residual outside) against the exact distance to that link.
- whole robot: `configs` random configurations within the joint limits, around each posed robot the
  same mix (links drawn uniformly); `RobotSDF.query` against the minimum over the posed links.

Errors are reported in mm as MAE and RMSE over All points, Near (|d| < 0.05 m) and Far (0.05 <= |d|
< 0.15 m). Sets are cached under `$SAMP_CACHE_DIR/robot_sdf_eval`, keyed by the robot's assets, the
link boxes and this config.
"""

from __future__ import annotations

import hashlib
import json
import statistics
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import torch

from samp.paths import cache_dir, write_cache_file
from samp.robot_sdf.samples import link_signed_distance

__all__ = ["EVAL_FORMAT", "PAPER_TABLE_III", "SDFEvalConfig", "error_metrics", "evaluate_methods",
           "heldout_link_set", "heldout_robot_set", "render_table", "robot_signed_distance", "time_query"]

EVAL_FORMAT = "robot-sdf-eval-v1"
TABLE_MD, TABLE_JSON, RECORDING = "robot_sdf_table.md", "robot_sdf_table.json", "robot_sdf.rrd"
BANDS = {"all": (0.0, float("inf")), "near": (0.0, 0.05), "far": (0.05, 0.15)}  # |d| ranges [m]
# The paper's Table III (mm; train s; inference ms), for side-by-side reading.
PAPER_TABLE_III = {
    "NN-SDF": [3.87, 1.33, 4.76, 7.11, 3.54, 7.97, 690, 5.22],
    "RDF (N=8)": [4.70, 2.95, 5.32, 7.52, 4.85, 8.24, 870, 1.88],
    "RDF (N=24)": [3.59, 1.2, 4.42, 6.99, 3.55, 7.82, 14658, 14.25],
    "SAMP": [3.30, 0.72, 4.22, 6.81, 3.26, 7.65, 80, 2.58],
}


@dataclass
class SDFEvalConfig:
    """The robot SDF accuracy evaluation (Table III): sizes and seed of the held-out sets, and what else
    to measure. (Rollout evaluation has its own `samp.eval.config.EvalConfig`.)"""

    link_points: int = 20_000  # per link, half near the surface, half uniform in its box
    configs: int = 20  # random configurations of the whole-robot set
    robot_points: int = 5_000  # per configuration, half near, half uniform
    noise: list[float] = field(default_factory=lambda: [0.0025, 0.01, 0.03])  # metres
    seed: int = 20240601
    timing_batches: list[int] = field(default_factory=lambda: [1, 50])  # configurations of 1024-ish robot points
    recording: bool = True  # write the offset-layer recording
    recording_spacing: float = 0.004  # metres between the recording's slice samples

    def __post_init__(self):
        if min(self.link_points, self.configs, self.robot_points) < 2 or not self.noise:
            raise ValueError(f"evaluation sizes must be >= 2 and noise non-empty, got {self}")


def _near_points(rng, mesh, count: int, noise: list[float]) -> np.ndarray:
    """Surface samples moved along random unit directions by N(0, sigma), sigma cycling through `noise`."""
    import trimesh

    surface, _ = trimesh.sample.sample_surface(mesh, count, seed=rng)
    direction = rng.normal(size=(count, 3))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    sigma = np.asarray(noise)[np.arange(count) % len(noise)]
    return surface + direction * rng.normal(size=(count, 1)) * sigma[:, None]


def _cache_key(robot, centres, scales, cfg: SDFEvalConfig, kind: str) -> str:
    key = {"format": EVAL_FORMAT, "kind": kind, "asset": robot.asset_hash, "links": list(robot.link_names),
           "centres": np.round(np.asarray(centres, dtype=np.float64), 9).tolist(),
           "scales": np.round(np.asarray(scales, dtype=np.float64), 9).tolist(),
           "cfg": {k: v for k, v in asdict(cfg).items() if k not in ("timing_batches", "recording", "recording_spacing")}}
    return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]


def _cached(path: Path, build) -> dict[str, np.ndarray]:
    if path.is_file():
        with np.load(path) as z:
            return dict(z)
    arrays = build()
    write_cache_file(path, lambda f: np.savez(f, **arrays))
    return arrays


def heldout_link_set(robot, centres, scales, cfg: SDFEvalConfig) -> dict[str, np.ndarray]:
    """points (P, 3) in their link frames [m], link (P,), sdf (P,) exact [m]."""
    centres, scales = np.asarray(centres, dtype=np.float64), np.asarray(scales, dtype=np.float64)

    def build():
        rng = np.random.default_rng(cfg.seed)
        points, links, sdf = [], [], []
        for i, name in enumerate(robot.link_names):
            geom, half = robot.geometry[name], cfg.link_points // 2
            p = np.concatenate([_near_points(rng, geom.mesh, half, cfg.noise),
                                centres[i] + rng.uniform(-scales[i], scales[i], size=(cfg.link_points - half, 3))])
            points.append(p)
            links.append(np.full(len(p), i))
            sdf.append(link_signed_distance(geom, p))
        return {"points": np.concatenate(points), "link": np.concatenate(links), "sdf": np.concatenate(sdf)}

    key = _cache_key(robot, centres, scales, cfg, "link")
    return _cached(cache_dir("robot_sdf_eval") / f"{robot.name}-link-{key}.npz", build)


def _link_poses(robot, q: np.ndarray) -> np.ndarray:
    """(C, n) -> (C, L, 4, 4) float64 link poses in the base frame."""
    with torch.no_grad():
        fk = robot.fk(torch.as_tensor(q, dtype=robot.dtype, device=robot.device))
    return np.stack([fk[name].double().cpu().numpy() for name in robot.link_names], axis=1)


def robot_signed_distance(robot, points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """(K, 3) base-frame points, (L, 4, 4) link poses -> (K,) exact distance [m] to the posed robot:
    the minimum over links of trimesh's distance, computed only where a link can beat the best so far
    (each convex part's largest face-plane value is a lower bound of its distance)."""
    local = [(points - T[:3, 3]) @ T[:3, :3] for T in pose]  # (K, 3) per link
    bound = np.stack([robot.geometry[n].inside_depth(p) for n, p in zip(robot.link_names, local)], axis=1)  # (K, L)
    best = np.full(len(points), np.inf)
    first = bound.argmin(axis=1)
    for rank in range(2):  # the most promising link first, then any other that may be closer
        for i, name in enumerate(robot.link_names):
            need = (first == i) if rank == 0 else ((first != i) & (bound[:, i] < best))
            if need.any():
                best[need] = np.minimum(best[need], link_signed_distance(robot.geometry[name], local[i][need]))
    return best


def heldout_robot_set(robot, centres, scales, cfg: SDFEvalConfig) -> dict[str, np.ndarray]:
    """q (C, n) radians, points (C, K, 3) base frame, sdf (C, K) exact [m]."""
    centres, scales = np.asarray(centres, dtype=np.float64), np.asarray(scales, dtype=np.float64)

    def build():
        rng = np.random.default_rng(cfg.seed + 1)
        lo, hi = robot.joint_limits.double().cpu().numpy().T
        q = rng.uniform(lo, hi, size=(cfg.configs, robot.dof))
        poses = _link_poses(robot, q)
        L, half = len(robot.link_names), cfg.robot_points // 2
        all_points, all_sdf = [], []
        for pose in poses:
            link = rng.integers(L, size=cfg.robot_points)
            local = np.empty((cfg.robot_points, 3))
            for i, name in enumerate(robot.link_names):
                near, uni = np.flatnonzero(link[:half] == i), half + np.flatnonzero(link[half:] == i)
                local[near] = _near_points(rng, robot.geometry[name].mesh, len(near), cfg.noise)
                local[uni] = centres[i] + rng.uniform(-scales[i], scales[i], size=(len(uni), 3))
            world = np.einsum("kij,kj->ki", pose[link, :3, :3], local) + pose[link, :3, 3]
            all_points.append(world)
            all_sdf.append(robot_signed_distance(robot, world, pose))
        return {"q": q, "points": np.stack(all_points), "sdf": np.stack(all_sdf)}

    key = _cache_key(robot, centres, scales, cfg, "robot")
    return _cached(cache_dir("robot_sdf_eval") / f"{robot.name}-robot-{key}.npz", build)


def error_metrics(pred: np.ndarray, truth: np.ndarray) -> dict[str, float]:
    """MAE and RMSE [mm] over All / Near / Far (by the true |d|), plus point counts."""
    err, dist = (np.asarray(pred) - truth).ravel() * 1000, np.abs(truth).ravel()
    out = {}
    for band, (lo, hi) in BANDS.items():
        sel = (dist >= lo) & (dist < hi)
        e = err[sel]
        out[f"mae_{band}_mm"] = float(np.abs(e).mean()) if len(e) else float("nan")
        out[f"rmse_{band}_mm"] = float(np.sqrt(np.square(e).mean())) if len(e) else float("nan")
        out[f"count_{band}"] = int(sel.sum())
    return out


@torch.no_grad()
def _predict_links(model, data: dict, chunk: int = 1 << 16) -> np.ndarray:
    dtype, device = model.robot.dtype, model.robot.device
    points = torch.as_tensor(data["points"], dtype=dtype, device=device)
    link = torch.as_tensor(data["link"], dtype=torch.long, device=device)
    return torch.cat([model.local_distance(points[i:i + chunk], link[i:i + chunk])
                      for i in range(0, len(points), chunk)]).double().cpu().numpy()


@torch.no_grad()
def _predict_robot(model, data: dict) -> np.ndarray:
    dtype, device = model.robot.dtype, model.robot.device
    out = []
    for q, points in zip(data["q"], data["points"]):
        out.append(model.query(torch.as_tensor(points[None], dtype=dtype, device=device),
                               torch.as_tensor(q[None], dtype=dtype, device=device))[0].double().cpu().numpy())
    return np.stack(out)


@torch.no_grad()
def time_query(model, batch: int, seed: int = 0, min_time: float = 0.3) -> float:
    """Median milliseconds of `model.query` on the robot points (M of them, 1024 for the arms here) at
    `batch` random configurations: the policy's use."""
    robot = model.robot
    lo, hi = robot.joint_limits.T.to(robot.dtype)
    g = torch.Generator().manual_seed(seed)
    q = (lo + (hi - lo) * torch.rand(batch, robot.dof, generator=g, dtype=robot.dtype)).to(robot.device)
    points = robot.transform_points(q)
    sync = torch.cuda.synchronize if points.is_cuda else (lambda: None)
    model.query(points, q)
    sync()
    times, start = [], time.perf_counter()
    while len(times) < 3 or (time.perf_counter() - start < min_time and len(times) < 200):
        t0 = time.perf_counter()
        model.query(points, q)
        sync()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def evaluate_methods(robot, methods: dict, cfg: SDFEvalConfig, out_dir: Path | str | None = None) -> dict:
    """Evaluate `methods` ({label: {"model": RobotSDF, "train_time_s": float}}) on the same held-out sets.

    All models must share the robot and the link boxes (they were trained on one sample set). Writes
    `robot_sdf_table.md`, `robot_sdf_table.json` and (with `cfg.recording`) `robot_sdf.rrd` to `out_dir`.
    """
    first = next(iter(methods.values()))["model"]
    centres, scales = first.centres.double().cpu().numpy(), first.scales.double().cpu().numpy()
    for label, entry in methods.items():
        m = entry["model"]
        if m.robot.asset_hash != robot.asset_hash or not np.allclose(m.scales.double().cpu().numpy(), scales):
            raise ValueError(f"method {label!r} was trained for other links or boxes than {list(methods)[0]!r}; "
                             "evaluate models trained on the same samples together")
    links, whole = heldout_link_set(robot, centres, scales, cfg), heldout_robot_set(robot, centres, scales, cfg)
    results = {}
    for label, entry in methods.items():
        model = entry["model"].eval()
        per_link = _predict_links(model, links)
        res = {"per_link": error_metrics(per_link, links["sdf"]),
               "whole_robot": error_metrics(_predict_robot(model, whole), whole["sdf"]),
               "per_link_mae_mm": {name: float(np.abs(per_link - links["sdf"])[links["link"] == i].mean() * 1000)
                                   for i, name in enumerate(robot.link_names)},
               "train_time_s": entry.get("train_time_s"),
               "infer_ms": {str(b): time_query(model, b) for b in cfg.timing_batches}}
        results[label] = res
    report = {"robot": robot.name, "robot_asset_hash": robot.asset_hash, "config": asdict(cfg),
              "points": {"per_link": int(len(links["sdf"])), "whole_robot": int(whole["sdf"].size)},
              "methods": results}
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        (out / TABLE_JSON).write_text(json.dumps(report, indent=2))
        (out / TABLE_MD).write_text(render_table(report))
        if cfg.recording:
            from samp.robot_sdf.viz import write_offset_recording

            write_offset_recording(out / RECORDING, robot, {k: v["model"] for k, v in methods.items()},
                                   spacing=cfg.recording_spacing)
    return report


def _fmt(x) -> str:
    return "-" if x is None or (isinstance(x, float) and np.isnan(x)) else (f"{x:.2f}" if abs(x) < 1000 else f"{x:.0f}")


def render_table(report: dict) -> str:
    """Markdown tables in the layout of the paper's Table III, whole robot first, then per link."""
    timing = [str(b) for b in report["config"]["timing_batches"]]
    header = ["method", "MAE All", "MAE Near", "MAE Far", "RMSE All", "RMSE Near", "RMSE Far", "train [s]",
              *[f"infer {b}x{'M'} [ms]" for b in timing]]
    lines = [f"# Robot SDF accuracy ({report['robot']}), Table III layout", "",
             "Errors in mm against trimesh; Near: |d| < 0.05 m, Far: 0.05-0.15 m. Inference: `query` on the robot's "
             "M robot points at 1 and 50 configurations."]
    for key, title in (("whole_robot", f"Whole robot ({report['points']['whole_robot']} points at "
                                       f"{report['config']['configs']} random configurations)"),
                       ("per_link", f"Per link ({report['points']['per_link']} held-out points in link frames)")):
        lines += ["", f"## {title}", "", "| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
        for label, res in report["methods"].items():
            m = res[key]
            row = [label, *[_fmt(m[f"{s}_{b}_mm"]) for s in ("mae", "rmse") for b in ("all", "near", "far")],
                   _fmt(res["train_time_s"]), *[_fmt(res["infer_ms"][b]) for b in timing]]
            lines.append("| " + " | ".join(row) + " |")
    lines += ["", "## The paper's Table III (Franka Panda, RTX 3080 Ti; inference time of its own setting)", "",
              "| method | MAE All | MAE Near | MAE Far | RMSE All | RMSE Near | RMSE Far | train [s] | infer [ms] |",
              "|---|---|---|---|---|---|---|---|---|"]
    lines += ["| " + " | ".join([k, *[f"{v:g}" for v in vals]]) + " |" for k, vals in PAPER_TABLE_III.items()]
    return "\n".join(lines) + "\n"
