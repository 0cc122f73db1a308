"""What the bench suites share: the options every suite reads, timing, machine info, the table and the JSON report,
and the fixtures two suites build alike (untrained policy systems, the two-scene problem sets)."""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import time
from pathlib import Path
from typing import Callable

import torch

# The header of the suites whose table compares samp with a baseline as a ratio.
HEADER = ["what", "samp", "baseline", "ratio"]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    """The options every suite reads; each suite module adds its own after these."""
    ap.add_argument("--out", type=Path, help="write the JSON report here")
    ap.add_argument("--device", default="cpu", help="cpu or cuda")
    ap.add_argument("--robot", default="panda")


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


def print_table(args: argparse.Namespace, table: list[list]) -> None:
    """The suite's table (first row: the header), columns right-aligned to their widest cell."""
    widths = [max(len(str(r[i])) for r in table) for i in range(len(table[0]))]
    ratios = "; ratios are baseline time / samp time" if table[0] == HEADER else ""
    print(f"suite {args.suite} ({args.robot}, {args.device}){ratios}")
    for r in table:
        print("  ".join(str(c).rjust(w) for c, w in zip(r, widths)))


def write_report(args: argparse.Namespace, metrics: dict) -> None:
    """The flat JSON report to --out, if given. `config` is every option as parsed (after the suite ran: eval
    replaces --n-e with a trained policy's own), so a report says how it was made."""
    report = {"suite": args.suite, "metrics": metrics, "machine": machine(torch.device(args.device)),
              "config": {k: v for k, v in vars(args).items() if k not in ("out", "suite")}}
    if args.out:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2, default=str))  # paths as strings
        print(f"wrote {args.out}")


def untrained_policy_system(robot, robot_name: str, robot_sdf: str | dict = "robot_sdf_hash", model: dict | None = None,
                            artifact: str | None = None, **system):
    """A PolicySystem (network `model` keys over the paper widths of `PolicyConfig`, other PolicySystem arguments
    in `system`) around an untrained robot SDF of the architecture conf/model/ROBOT_SDF.yaml (or that model node,
    as a dict), or the trained robot SDF `artifact` (a robot_sdf.pt)."""
    from omegaconf import OmegaConf

    from samp.paths import conf_dir
    from samp.policy.system import PolicySystem, read_robot_sdf
    from samp.robot_sdf.artifact import describe, net_spec
    from samp.robot_sdf.model import UnifiedHashSDF
    from samp.robot_sdf.samples import link_normalisation

    if artifact:
        payload = read_robot_sdf(artifact)
    else:
        node = robot_sdf if isinstance(robot_sdf, dict) else OmegaConf.load(conf_dir() / "model" / f"{robot_sdf}.yaml")
        kwargs = {k: v for k, v in OmegaConf.to_container(OmegaConf.create(node)).items() if not k.startswith("_")}
        kwargs["num_links"] = len(robot.link_names)
        net = UnifiedHashSDF(**kwargs)
        centres, scales = link_normalisation(robot, 0.02)
        payload = {"info": describe(robot, net_spec(net, kwargs), "bench", torch.tensor(centres), torch.tensor(scales)),
                   "state_dict": net.state_dict()}
    return PolicySystem(robot=robot_name, robot_sdf_payload=payload, model=model, **system)


def bench_scenes() -> list:
    """The two scenes the eval and baselines suites draw their problems from."""
    from samp.scene import generate_scene

    return [generate_scene("tabletop", seed=0), generate_scene("shelf", seed=1)]


def bench_problems(exact, scenes: list, count: int, named: bool = False) -> list:
    """ceil(count / len(scenes)) problems per scene, start/goal pairs as the expert samples them (no planning
    needed); a few extra are drawn since sampling may find no goal. `named`: bench{scene}/{k} problem names."""
    from samp.eval import Problem
    from samp.expert import load_expert_config, sample_problems

    problems, per_scene = [], -(-count // len(scenes))
    for i, scn in enumerate(scenes):
        drawn = sample_problems(exact, scn, per_scene + 5, seed=i, cfg=load_expert_config())
        problems += [Problem(scn, p.q_start, p.q_goal, split="train", robot=exact.name,
                             **({"name": f"bench{i}/{k}"} if named else {}))
                     for k, p in enumerate(drawn) if p.q_goal is not None][:per_scene]
    return problems
