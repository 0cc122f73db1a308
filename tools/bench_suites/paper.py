"""`paper` suite: a dry run of the paper-scale recipes (conf/experiment/samp_paper.yaml and samp_paper_ours.yaml;
--experiments) before anything is trained or generated. Per recipe: its key settings as composed, one training step
measured on this machine at the recipe's width, n_e and batch (an untrained network), the whole run's wall time
expected from that step (measured) beside the paper's own GPU figure (quoted, not measured: Table II, 1050 s per
epoch at n_e = 160 on an RTX 3080 Ti for 1.6 M samples, 160 epochs), the memory of one training step, and the disk
of the recipe's dataset (conf/dataset/<name>.yaml), estimated from two small datasets generated here and scene files
written with the spec's own first scenes' grids, scaled to the spec's counts.

The training step uses the policy suite's step (`policy.train_step`): random configurations, the scenes of a batch
drawn as the recipe's DataModule draws them (`scenes_per_batch`; 0: from every training scene alike), one real
anchor grid (the spec's first scene) standing for every scene (a step's cost does not depend on the grid's values).
An untrained robot SDF culls point-link pairs unlike a trained one: --robot-sdf ARTIFACT (a trained robot_sdf.pt;
its own architecture then) gives step times that hold.

Adds --experiments, --steps, --train-n-e and --disk-max-n-e; reads --robot-sdf (added by the policy suite).
"""

from __future__ import annotations

import argparse
import math
import resource
import statistics
import tempfile
import time
from pathlib import Path

import torch

from .policy import train_step

# The paper's own figures (Table II: training seconds per epoch by n_e on one RTX 3080 Ti, 1.6 M samples; 160 epochs).
PAPER_EPOCH_S = {40: 150, 70: 180, 100: 270, 130: 560, 160: 1050}
PAPER_SAMPLES, PAPER_GPU = 1_600_000, "RTX 3080 Ti"
DISK_TRAJECTORIES = (2, 6)  # demonstrations in the two small datasets whose difference gives bytes per trajectory


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--experiments", nargs="+", default=["samp_paper", "samp_paper_ours"],
                    help="paper: the training experiments (conf/experiment/) to dry-run")
    ap.add_argument("--steps", type=int, default=2,
                    help="paper: timed training steps per experiment (after one warm-up)")
    ap.add_argument("--train-n-e", type=int, default=None,
                    help="paper: n_e of the timed step (default: the experiment's own; smaller for a quick check)")
    ap.add_argument("--disk-max-n-e", type=int, default=None,
                    help="paper: grids above this n_e are not computed for the disk estimate but scaled by n_e^3 from "
                         "the largest computed (default: compute every resolution of the spec)")


def _settings(cfg) -> dict:
    """The composed config's keys that make a recipe the paper's or ours."""
    from omegaconf import OmegaConf

    s, m, d, loss, opt = cfg.system, cfg.model, cfg.datamodule, cfg.system.loss, cfg.system.optimizer
    sched = OmegaConf.to_container(s.scheduler, resolve=True) or {}
    return {"dataset": d.dataset, "n_e": d.n_e, "batch_size": d.batch_size, "scenes_per_batch": d.scenes_per_batch,
            "noise": d.noise, "epochs": cfg.trainer.max_epochs, "norm": m.norm, "registration": m.registration,
            "goal_features": m.goal_features,
            "widths": f"C={m.channels} env {list(m.env_hidden)} points {list(m.point_hidden)}",
            "robot_sdf": _robot_sdf(s.robot_sdf), "robot_sdf_tables": s.robot_sdf_tables,
            "robot_sdf_pairs": s.robot_sdf_pairs,
            "loss": f"lambda {loss.match:g}/{loss.collision:g}/{loss.config:g} margin {loss.d_margin:g} "
                    f"({loss.margin}) target {loss.d_target:g} tau {loss.tau:g}",
            "optimizer": f"{opt._target_.rsplit('.', 1)[-1]} lr {opt.lr:g} wd {opt.weight_decay:g}",
            "scheduler": " ".join([sched.get("_target_", "none").rsplit(".", 1)[-1]]
                                  + [f"{k}={v}" for k, v in sched.items() if not k.startswith("_")])}


def _last_epoch_lr(cfg) -> float:
    """The learning rate of the last epoch over the first, the scheduler stepped once per epoch as in training."""
    from hydra.utils import instantiate

    opt = instantiate(cfg.system.optimizer)([torch.nn.Parameter(torch.zeros(1))])
    sched = instantiate(cfg.system.scheduler)(opt) if cfg.system.scheduler else None
    first = lr = opt.param_groups[0]["lr"]
    for _ in range(int(cfg.trainer.max_epochs) - 1):
        opt.step()
        if sched is not None:
            sched.step()
        lr = opt.param_groups[0]["lr"]
    return lr / first


def _robot_sdf(ref: str) -> str:
    """The robot SDF a recipe names, with its hash grid's size when it is an experiment."""
    from samp.paths import conf_dir
    from samp.train import compose_train_config

    if not (conf_dir() / "experiment" / f"{ref}.yaml").is_file():
        return str(ref)
    enc = compose_train_config([f"experiment={ref}"]).model.encoding
    return f"{ref} (L={enc.levels}, 2^{enc.log2_table_size} rows, {enc.interpolation})"


def _rss_mb(field: str) -> float | None:
    """VmRSS / VmHWM of this process in MB (Linux), else None."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith(field + ":"):
                return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def _reset_peak() -> bool:
    """Reset this process's peak RSS (VmHWM; Linux), so that the next peak is one step's. Large blocks are then
    mapped and unmapped one by one (glibc's mallopt: a fixed mmap threshold), so that memory a step frees leaves the
    RSS instead of staying in the heap, where the next step would reuse it unseen."""
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        libc.mallopt(-3, 128 * 1024)  # M_MMAP_THRESHOLD: fixed, no longer raised as blocks are freed
        libc.mallopt(-1, 128 * 1024)  # M_TRIM_THRESHOLD: give freed heap tops back
        libc.malloc_trim(0)
        Path("/proc/self/clear_refs").write_text("5")
        return True
    except (OSError, AttributeError):
        return False


def _scene_index(k: int, scenes: int, batch: int, g: torch.Generator) -> torch.Tensor:
    """A batch's scene indices as the DataModule draws them: from k scenes, or (k = 0) every scene alike."""
    if k <= 0:
        return torch.randint(0, scenes, (batch,), generator=g)
    chosen = torch.randperm(scenes, generator=g)[:k]
    return chosen[torch.arange(batch) * min(k, scenes) // batch]


def _prepare(args, cfg, spec, grid: torch.Tensor, bounds, device: torch.device) -> dict:
    """The recipe's system (untrained) bound to `grid` for each of the spec's training scenes, and its training step
    on one batch of the recipe's size, run once (lazy state: the optimizer's moments, the robot SDF's tables)."""
    from omegaconf import OmegaConf

    from samp.data.binding import DatasetBinding
    from samp.robot import load_robot

    from .common import untrained_policy_system

    robot = load_robot(cfg.robot.name)
    sys_cfg = OmegaConf.to_container(cfg.system, resolve=True)
    sdf_model = None
    if not args.robot_sdf:
        from samp.train import compose_train_config

        sdf_model = OmegaConf.to_container(compose_train_config([f"experiment={cfg.system.robot_sdf}"]).model)
    system = untrained_policy_system(robot, robot.name, sdf_model or "robot_sdf_hash", model=sys_cfg["model"],
                                     artifact=args.robot_sdf, loss=sys_cfg["loss"], optimizer=sys_cfg["optimizer"],
                                     scheduler=sys_cfg["scheduler"], robot_sdf_tables=sys_cfg["robot_sdf_tables"],
                                     robot_sdf_pairs=sys_cfg["robot_sdf_pairs"]).to(device)
    n_e, scenes, batch = grid.shape[0], spec.train_scenes, int(cfg.datamodule.batch_size)
    grids = grid.expand(scenes, n_e, n_e, n_e)  # one grid's memory for every scene index
    system.bind(DatasetBinding(robot.name, robot.asset_hash, "bench", n_e, bounds, grids))
    g = torch.Generator().manual_seed(0)
    step = train_step(system, robot, g, device, batch)
    scene = _scene_index(int(cfg.datamodule.scenes_per_batch), scenes, batch, g).to(device)
    sync = torch.cuda.synchronize if device.type == "cuda" else (lambda: None)
    system.train()
    step(scene)
    sync()
    return {"run": lambda: (step(scene), sync()), "distinct_scenes": int(scene.unique().numel()), "n_e": n_e,
            "params": sum(p.numel() for p in system.net.parameters()), "grids_mb": scenes * n_e ** 3 * 4 / 2**20}


def _seconds(prepared: dict, steps: int) -> float:
    """Median wall seconds of `steps` training steps."""
    times = []
    for _ in range(max(1, steps)):
        t0 = time.perf_counter()
        prepared["run"]()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _memory(prepared: dict, device: torch.device) -> dict:
    """One more training step's memory: on CUDA torch's allocated peak over what was allocated before it; on a CPU
    the peak RSS over the RSS before it (after `_reset_peak`, which slows later steps: so after all timing)."""
    if device.type == "cuda":
        torch.cuda.reset_peak_memory_stats(device)
        before = torch.cuda.memory_allocated(device) / 2**20
        prepared["run"]()
        peak = torch.cuda.max_memory_allocated(device) / 2**20
        return {"peak_mb": peak, "step_mb": peak - before}
    reset, before = _reset_peak(), _rss_mb("VmRSS")
    prepared["run"]()
    peak = _rss_mb("VmHWM") if reset else None
    if peak is None:  # no /proc: the process's lifetime peak, and no figure for the step alone
        return {"peak_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024, "step_mb": None}
    return {"peak_mb": peak, "step_mb": peak - before}


def _spec_scenes(spec, count: int) -> list:
    """The spec's first `count` scenes (one per generator when count = len(generators)), as generation draws them."""
    from samp.scene.registry import scene_from_config

    return [scene_from_config(spec.generator_config(j.generator), j.seed) for j in spec.scene_jobs()[:count]]


def _grid_bytes(spec, scenes: list, max_n_e: int | None, root: Path) -> tuple[dict[int, float], list[int]]:
    """Mean bytes one grid adds to a scene file, per n_e of the spec: files written with and without it (the
    writer's own compression), over `scenes`; above `max_n_e`, scaled by n_e^3 from the largest computed. Also the
    n_e computed."""
    from samp.data.mcap_io import SceneRecord, write_scene_file

    def size(scene, grids):
        path = root / "grid.mcap"
        write_scene_file(path, SceneRecord(scene, 0, "train", ["q"], grids=grids))
        return path.stat().st_size

    computed = [n for n in spec.resolutions if max_n_e is None or n <= max_n_e] or [min(spec.resolutions)]
    out = {n: statistics.mean(size(s, {n: s.anchor_grid(n)}) - size(s, {}) for s in scenes) for n in computed}
    top = max(computed)
    out.update({n: out[top] * (n / top) ** 3 for n in spec.resolutions if n not in out})
    return {n: out[n] for n in spec.resolutions}, computed


def _trajectory_bytes(spec, root: Path) -> tuple[float, float]:
    """(bytes per stored trajectory, bytes per scene file besides its trajectories and grids): two one-scene
    datasets of the spec's expert and detour share that differ only in their number of demonstrations."""
    from samp.data import DatasetSpec, generate, read_manifest

    sizes = []
    for t in DISK_TRAJECTORIES:
        small = {**{k: v for k, v in spec.resolved().items() if k in DatasetSpec.__dataclass_fields__},
                 "name": f"bench_disk{t}", "scene_namespace": "bench_disk", "train_scenes": 1, "val_scenes": 0,
                 "test_scenes": 0, "trajectories_per_scene": t, "eval_problems_per_scene": 1, "resolutions": [2]}
        folder = generate(small, workers=1, root=root, progress=False)
        counts = read_manifest(folder)["counts"]
        stored = counts["trajectories"] + counts["eval_solved"]
        sizes.append((stored, sum(f.stat().st_size for f in folder.glob("*.mcap"))))
    (n0, b0), (n1, b1) = sizes
    per = (b1 - b0) / max(1, n1 - n0)
    return per, max(0.0, b0 - n0 * per)


def _disk(args, spec) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        per_traj, per_file = _trajectory_bytes(spec, Path(tmp))
        scenes = _spec_scenes(spec, len(spec.generators))
        grids, computed = _grid_bytes(spec, scenes, args.disk_max_n_e, Path(tmp))
    trajectories = sum(j.trajectories + j.eval_problems for j in spec.scene_jobs())
    total = spec.num_scenes * (per_file + sum(grids.values())) + trajectories * per_traj
    return {"per_trajectory_bytes": per_traj, "per_file_bytes": per_file, "trajectories": trajectories,
            "grid_bytes": grids, "total_bytes": total, "scenes": scenes, "computed": computed}


def _hours(seconds: float | None) -> str:
    if seconds is None:
        return "n/a"
    return f"{seconds / 3600:,.1f} h" if seconds < 72 * 3600 else f"{seconds / 86400:,.1f} days"


def _expected(cfg, spec, step_s: float) -> dict:
    """The run's size (samples and steps per epoch, epochs) and its wall time: from the measured step, and from the
    paper's seconds per epoch at the recipe's n_e (Table II), per sample of this spec."""
    samples = spec.train_scenes * spec.trajectories_per_scene * (spec.expert_config().waypoints - 1)
    steps = math.ceil(samples / int(cfg.datamodule.batch_size))
    epochs, n_e = int(cfg.trainer.max_epochs), int(cfg.datamodule.n_e)
    paper = PAPER_EPOCH_S[n_e] * samples / PAPER_SAMPLES * epochs if n_e in PAPER_EPOCH_S else None
    return {"samples": samples, "steps_per_epoch": steps, "epochs": epochs, "expected_train_s": step_s * steps * epochs,
            "paper_gpu_train_s": paper}


def _training_rows(args, measured: dict, device: torch.device) -> list[list]:
    cells = lambda f: [f(measured[n]) for n in args.experiments]  # noqa: E731
    here = f"measured here ({device.type}, {torch.get_num_threads()} threads)"
    cuda = device.type == "cuda"
    return [
        ["training step", *cells(lambda m: f"{m['step_s']:.3f} s"), f"{here}, median of {args.steps}"],
        ["  at n_e, B, distinct scenes", *cells(lambda m: f"{m['n_e']}, {m['batch']}, {m['distinct_scenes']}"),
         "the batch timed"],
        ["  robot SDF of the timed step", *cells(lambda m: args.robot_sdf or "untrained, the recipe's size"),
         "--robot-sdf" if args.robot_sdf else "an untrained one culls pairs unlike a trained one"],
        ["  network parameters", *cells(lambda m: f"{m['params'] / 1e6:.2f} M"), "the paper: about 3.1 M"],
        ["  samples per epoch, steps per epoch, epochs",
         *cells(lambda m: f"{m['samples']:,}, {m['steps_per_epoch']:,}, {m['epochs']}"), "spec and config"],
        ["expected training wall time", *cells(lambda m: _hours(m["expected_train_s"])),
         f"{here}: step x steps x epochs (no validation, no rollouts)"],
        ["  by the paper's GPU figure", *cells(lambda m: _hours(m["paper_gpu_train_s"])),
         f"the paper, not measured: Table II s/epoch at the recipe's n_e ({PAPER_EPOCH_S[160]} s at 160, {PAPER_GPU}), "
         "per sample of the spec"],
        ["memory of one training step", *cells(lambda m: "n/a" if m["step_mb"] is None else f"{m['step_mb']:.0f} MB"),
         "measured: " + ("torch's allocated peak over the step" if cuda else "peak RSS over the step")],
        ["  peak (process)", *cells(lambda m: f"{m['peak_mb']:.0f} MB"), "measured"],
        ["  grids the DataModule holds", *cells(lambda m: f"{m['grids_mb']:.0f} MB"), "computed: scenes x n_e^3 x 4 B"],
    ]


def _disk_rows(name: str, d: dict, columns: int) -> list[list]:
    pad = [""] * (columns - 1)
    grids = " ".join(f"n{n}: {b / 2**20:.1f} MB" for n, b in d["grid_bytes"].items())
    scaled = "" if len(d["computed"]) == len(d["grid_bytes"]) else f" at n_e {d['computed']}, the others scaled"
    return [[f"dataset {name!r} on disk (estimate)", f"{d['total_bytes'] / 2**30:.2f} GiB", *pad,
             "scaled from small datasets generated here"],
            ["  per trajectory, per scene file",
             f"{d['per_trajectory_bytes'] / 1e3:.1f} kB, {d['per_file_bytes'] / 1e3:.0f} kB", *pad,
             f"{d['trajectories']:,} trajectories (all solved)"],
            ["  per scene, grids", grids, *pad, f"measured on its first {len(d['scenes'])} scenes{scaled}"]]


def run(args) -> tuple[dict, list[list]]:
    """Settings, the measured step and the expected wall time, memory, and the disk of each recipe's dataset."""
    from samp.data import load_spec
    from samp.train import compose_train_config

    device = torch.device(args.device)
    cfgs = {name: compose_train_config([f"experiment={name}"]) for name in args.experiments}
    metrics, rows = {"threads": torch.get_num_threads()}, [["what", *args.experiments, "source"]]
    settings = {name: _settings(cfg) for name, cfg in cfgs.items()}
    for key in settings[args.experiments[0]]:
        rows.append([f"  {key}", *[str(settings[n][key]) for n in args.experiments], "config"])
    lr_end = {n: _last_epoch_lr(cfg) for n, cfg in cfgs.items()}
    rows.append(["  learning rate in the last epoch / first", *[f"{lr_end[n]:.1e}" for n in args.experiments],
                 "config (scheduler stepped per epoch)"])
    disks, measured, prepared = {}, {}, {}
    for name, cfg in cfgs.items():
        spec = load_spec(str(cfg.datamodule.dataset))
        if spec.name not in disks:
            print(f"paper: disk of the {spec.name!r} dataset (small datasets, grids of its first scenes) ...", flush=True)
            disks[spec.name] = _disk(args, spec)
        n_e, batch = args.train_n_e or int(cfg.datamodule.n_e), int(cfg.datamodule.batch_size)
        print(f"paper: {name}: {args.steps} training steps at n_e = {n_e}, B = {batch} ...", flush=True)
        first = disks[spec.name]["scenes"][0]
        prepared[name] = _prepare(args, cfg, spec, first.anchor_grid(n_e).float(), first.bounds, device)
        step_s = _seconds(prepared[name], args.steps)
        measured[name] = {**{k: v for k, v in prepared[name].items() if k != "run"}, "batch": batch, "step_s": step_s,
                          **_expected(cfg, spec, step_s)}
        metrics.update({f"{name}/lr_last_over_first": lr_end[name], f"{name}/dataset": spec.name,
                        f"{name}/dataset_bytes": disks[spec.name]["total_bytes"]})
    for name in args.experiments:  # after every timed step: the CPU measurement slows the steps after it
        print(f"paper: {name}: the memory of one more step ...", flush=True)
        measured[name].update(_memory(prepared[name], device))
        metrics.update({f"{name}/{k}": v for k, v in measured[name].items()})
    rows += _training_rows(args, measured, device)
    for name, d in disks.items():
        metrics.update({f"disk/{name}/{k}": v for k, v in d.items() if k not in ("grid_bytes", "scenes", "computed")})
        metrics.update({f"disk/{name}/grid_n{n}_bytes": b for n, b in d["grid_bytes"].items()})
        rows += _disk_rows(name, d, len(args.experiments))
    return metrics, rows
