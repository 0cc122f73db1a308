"""`eval` suite: rollouts per second of the batched engine (--problems problems over two scenes, or spread over
the standing benchmark's unseen scenes with --benchmark NAME; grids at --n-e, the straight-line policy, or
--policy-run RUN_DIR's trained policy at its own n_e) and of a full evaluation with pybullet checks; baseline: one
problem at a time. The policy's per-problem solution time (B = 1) against the expert's planning time, planned
afresh with OMPL in the same run, on --expert-problems of them.

Adds --problems (also read by the perception suite), --n-e (also read by the baselines suite), --expert-problems,
--policy-run (also read by the policy suite), --benchmark and --stride."""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Callable

import torch

from .common import HEADER, bench_problems, bench_scenes


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--problems", type=int, default=100, help="eval: problems rolled out (over two scenes)")
    ap.add_argument("--n-e", type=int, default=100, help="eval: anchors per axis of the grids handed to the policy")
    ap.add_argument("--expert-problems", type=int, default=10, help="eval: problems the expert plans afresh")
    ap.add_argument("--policy-run", help="eval: a trained policy's run folder (default: the straight-line policy)")
    ap.add_argument("--benchmark", help="eval: take the problems from this standing benchmark (e.g. unseen; built "
                    "when missing) instead of two generated scenes")
    ap.add_argument("--stride", type=float, default=1.0, help="eval: the --policy-run policy's stride (up to this many "
                    "times each predicted step; 1: as trained)")


def _load_policy(args, device: torch.device):
    """A trained policy (its own n_e, which replaces --n-e in `args`), else the straight line at --n-e."""
    from samp.eval import StraightLinePolicy
    from samp.robot import load_robot

    if args.policy_run:
        from samp.eval import load_planner

        policy = load_planner(args.policy_run, **_stride(args))
        if hasattr(policy, "system"):
            policy.system.to(device)
        args.n_e = policy.n_e
        return policy
    return StraightLinePolicy(load_robot(args.robot, dtype=torch.float32).to(device), n_e=args.n_e)


def _stride(args) -> dict:
    """The planner option of --stride (none at 1, so that policies without strides load as before)."""
    return {} if args.stride == 1.0 else {"stride": args.stride}


def _median_time(fn: Callable, repeats: int) -> tuple[float, object]:
    """(median seconds, last result) over `repeats` calls: the machine may be shared."""
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times), out


def _expert_times(exact, subset: list) -> list[float]:
    """The expert's planning time for each problem of `subset`, planned afresh, one planner per scene."""
    from samp.expert import ExpertPlanner

    expert_times, by_scene = [], {}
    for p in subset:
        by_scene.setdefault(id(p.scene), []).append(p)
    for mine in by_scene.values():
        with ExpertPlanner(exact, mine[0].scene) as planner:
            expert_times += [planner.plan(p.q_start, p.q_goal, seed=0).stats["planning_time"] for p in mine]
    return expert_times


def _problems(args, exact) -> list:
    """--problems problems: from the benchmark's stored ones (spread over its scenes), or two generated scenes."""
    if args.benchmark:
        from samp.eval import problems_from_dataset
        from samp.eval.benchmark import detour_only, open_benchmark

        bench = open_benchmark(args.benchmark)  # bench_hard: its problems drawn to need a detour, as evaluated
        return problems_from_dataset(bench, "test", args.problems, seed=0, detour_only=detour_only(bench))
    return bench_problems(exact, bench_scenes(), args.problems)[:args.problems]


def _report(args, label: str, n: int, t: dict, batched: list, single: list, full: dict,
            expert_times: list[float], rows: list[int]) -> tuple[dict, list[list]]:
    """Metrics and table rows for `n` problems from the timings `t` (batched, single, full, full_single: seconds
    for all of them), the rollout results and the expert's planning times on the problems `rows`."""
    policy_times = [single[i].solution_time for i in rows]
    steps = [len(r.trajectory) - 1 for r in batched]
    m = full["metrics"]["all"]
    step_batched = statistics.mean(s for r in batched for s in r.step_times)
    step_single = statistics.mean(s for r in single for s in r.step_times)
    expert_s, policy_s = statistics.mean(expert_times), statistics.mean(policy_times)
    metrics = {"problems": n, "n_e": args.n_e, "steps_mean": statistics.mean(steps),
               "rollout/batched_per_s": n / t["batched"], "rollout/single_per_s": n / t["single"],
               "rollout/speedup": t["single"] / t["batched"], "evaluate/batched_per_s": n / t["full"],
               "evaluate/single_per_s": n / t["full_single"], "evaluate/speedup": t["full_single"] / t["full"],
               "step/batched_ms": 1e3 * step_batched, "step/single_ms": 1e3 * step_single,
               "solution/policy_single_s": policy_s,
               "solution/policy_batched_s": statistics.mean(r.solution_time for r in batched),
               "solution/expert_s": expert_s, "solution/expert_vs_policy": expert_s / policy_s,
               f"{label}/success_rate": m["success_rate"], f"{label}/collision_rate": m["collision_rate"]}
    rows = [[f"rollouts ({n} problems, n_e={args.n_e}, {statistics.mean(steps):.0f} steps avg)",
             f"{n / t['batched']:.1f}/s batched", f"{n / t['single']:.1f}/s one at a time",
             f"{t['single'] / t['batched']:.1f}x"],
            ["rollouts + pybullet checks (evaluate)", f"{n / t['full']:.1f}/s batched",
             f"{n / t['full_single']:.1f}/s one at a time", f"{t['full_single'] / t['full']:.1f}x"],
            ["policy step call", f"{1e3 * step_batched:.2f} ms for B<={n}", f"{1e3 * step_single:.2f} ms for B=1",
             f"{step_single * n / step_batched:.1f}x per problem"],
            [f"solution time, {len(rows)} problems", f"{policy_s * 1e3:.1f} ms policy (B=1)",
             f"{expert_s:.3f} s expert planning", f"{expert_s / policy_s:.2f}x"],
            [f"{label} policy on these problems", f"success {m['success_rate']:.0%}",
             f"collision {m['collision_rate']:.0%}", ""]]
    return metrics, [HEADER, *rows]


def run(args) -> tuple[dict, list[list]]:
    """Batched rollouts against one problem at a time, and the policy's solution time against the expert's."""
    from samp.eval import RolloutConfig, evaluate, rollout
    from samp.robot import load_robot

    device = torch.device(args.device)
    exact = load_robot(args.robot, dtype=torch.float64)
    problems = _problems(args, exact)
    policy = _load_policy(args, device)
    grids = {id(p.scene): p.scene.anchor_grid(args.n_e) for p in problems}  # once per scene (disk-cached)
    source = lambda p, n_e: grids[id(p.scene)]  # noqa: E731
    batched_cfg, single_cfg = RolloutConfig(), RolloutConfig(batch_size=1)
    label = policy.name if args.policy_run else "straight"
    repeats = 1 if args.policy_run else 3

    rollout(policy, problems[:4], batched_cfg, source)  # warm-up
    t = {}
    t["batched"], batched = _median_time(lambda: rollout(policy, problems, batched_cfg, source), repeats)
    t["single"], single = _median_time(lambda: rollout(policy, problems, single_cfg, source), repeats)
    t["full"], full = _median_time(lambda: evaluate(policy, problems, batched_cfg, grids=source), repeats)
    t["full_single"], _ = _median_time(lambda: evaluate(policy, problems, single_cfg, grids=source), repeats)

    rows = list(range(0, len(problems), max(1, len(problems) // args.expert_problems)))[:args.expert_problems]
    subset = [problems[i] for i in rows]  # spread over the scenes
    metrics, table = _report(args, label, len(problems), t, batched, single, full, _expert_times(exact, subset), rows)
    if getattr(policy, "compiled", False):  # a SAMP policy whose default step is compiled: its torch path too
        from samp.eval import load_planner

        plain = load_planner(args.policy_run, compiled=False, **_stride(args))
        plain.system.to(device)
        times = [r.solution_time for r in rollout(plain, subset, single_cfg, source)]
        mine = metrics["solution/policy_single_s"]
        metrics["solution/policy_torch_path_single_s"] = statistics.mean(times)
        table.insert(5, [f"  the same {len(rows)} problems on the torch path (compiled=False)",
                         f"{statistics.mean(times) * 1e3:.1f} ms policy (B=1)", "",
                         f"{statistics.mean(times) / mine:.2f}x"])
    return metrics, table
