"""`baselines` suite: Table I's timing on --baseline-problems problems: per-step inference (B = 1) and solution
time of SAMP, MPiNet, MPNet, SIMPNet (the runs in --runs; untrained default-size networks for step times otherwise) and the
OMPL expert, expert_raw and ompl_sampling rows, as ratios to SAMP.

Adds --runs and --baseline-problems; reads --n-e (added by the eval suite) for the untrained networks' grids."""

from __future__ import annotations

import argparse
import statistics

import torch

from .common import bench_problems, bench_scenes, timeit, untrained_policy_system

HEADER = ["planner", "step [ms]", "step vs samp", "solution [s]", "solution vs samp", "reached/planned"]


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--runs", nargs="*", default=[], help="baselines: trained run folders (samp, mpinet, mpnet, simpnet); "
                    "those missing are timed as untrained networks of the default sizes")
    ap.add_argument("--baseline-problems", type=int, default=6, help="baselines: problems each planner solves")


def _baseline_planners(args, scenes) -> tuple[dict, set]:
    """name -> planner for the `baselines` suite: the runs in --runs (samp, mpinet, mpnet, simpnet by name),
    and untrained networks of the default sizes for those missing, bound to `scenes`' grids (MPiNet derives
    its obstacle points from them when bound); and the names of the untrained ones."""
    from hydra.utils import instantiate

    from samp.data.binding import DatasetBinding
    from samp.eval import load_planner
    from samp.policy import SAMPStepPolicy
    from samp.robot import load_robot
    from samp.train import compose_train_config

    planners = {}
    for run in args.runs:
        planner = load_planner(run)
        planners[planner.name] = planner
    missing = [k for k in ("samp", "mpinet", "mpnet", "simpnet") if k not in planners]
    for kind in missing:
        if kind == "samp":  # an untrained robot SDF of the default architecture costs what a trained one does
            system = untrained_policy_system(load_robot(args.robot), args.robot)
        else:
            system = instantiate(compose_train_config([f"+experiment={kind}", f"robot={args.robot}"]).system)
        robot = system.robot
        grids = torch.stack([scene.anchor_grid(args.n_e) for scene in scenes])  # (S, n_e, n_e, n_e)
        system.bind(DatasetBinding(robot.name, robot.asset_hash, "bench (untrained)", args.n_e, scenes[0].bounds,
                                   grids))
        system = system.to(torch.device(args.device)).eval()
        planners[kind] = SAMPStepPolicy(system) if kind == "samp" else system.planner()
    return planners, set(missing)


def _time_planners(args, planners: dict, untrained: set, problems: list, scenes: list) -> tuple[dict, dict, dict]:
    """name -> mean seconds per step, mean solution seconds and share solved, for the planners that have them."""
    from samp.eval import RolloutConfig, rollout

    step, solve, solved = {}, {}, {}
    for name, planner in planners.items():
        if hasattr(planner, "step"):  # a step policy: rollouts one problem at a time, timed by the engine
            results = rollout(planner, problems, RolloutConfig(batch_size=1), lambda p, n: p.scene.anchor_grid(n))
            step[name] = statistics.mean(t for r in results for t in r.step_times)
            solve[name] = statistics.mean(r.solution_time for r in results)
            solved[name] = statistics.mean(r.termination == "reached" for r in results)
            continue
        if name in ("mpnet", "simpnet"):  # one network call (B=1); MPNet plans only with a trained network
            step[name] = _network_call(args, planner, problems[0], scenes[0])
            if name == "mpnet" and name in untrained:
                continue
        answers = [planner.plan(p) for p in problems]
        solve[name] = statistics.mean(a.solution_time for a in answers)
        solved[name] = statistics.mean(a.trajectory is not None for a in answers)
    return step, solve, solved


def _network_call(args, planner, problem, scene) -> float:
    """Seconds of one call of an MPNet- or SIMPNet-style network at B = 1 (scene encoded beforehand)."""
    from samp.policy.network import normalize

    system = planner.system
    dev = system.device
    u, g = (normalize(torch.as_tensor(q, dtype=torch.float32, device=dev)[None], system.limits)
            for q in (problem.q_start, problem.q_goal))
    with torch.no_grad():
        code = system.net.encode(scene.anchor_grid(planner.n_e)[None].to(dev, torch.float32))
        return timeit(lambda: system.net(code, u, g), torch.device(args.device), min_time=0.05, repeats=3)


def run(args) -> tuple[dict, list[list]]:
    """Table I's timing columns on CPU: per-step inference and solution time of SAMP, MPiNet, MPNet and
    the OMPL expert rows on the same --baseline-problems problems (two scenes), as ratios to SAMP."""
    from samp.eval import ExpertTrajectoryPlanner
    from samp.eval.planners import EXPERT_VARIANTS
    from samp.expert import load_expert_config
    from samp.robot import load_robot

    exact = load_robot(args.robot, dtype=torch.float64)
    scenes = bench_scenes()
    problems = bench_problems(exact, scenes, args.baseline_problems, named=True)
    planners, untrained = _baseline_planners(args, scenes)
    planners["expert"] = ExpertTrajectoryPlanner("plan", exact)
    for name, overrides in EXPERT_VARIANTS.items():
        planners[name] = ExpertTrajectoryPlanner("plan", exact, load_expert_config(None, **overrides), name=name)
    step, solve, solved = _time_planners(args, planners, untrained, problems, scenes)
    metrics, rows = {"problems": len(problems), "n_e": args.n_e, "untrained": sorted(untrained)}, []
    for name in planners:
        s, t, ok = step.get(name), solve.get(name), solved.get(name)
        metrics.update({f"{name}/{k}": v for k, v in (("step_ms", s and 1e3 * s), ("solution_s", t), ("solved", ok),
                        ("step_vs_samp", s and s / step["samp"]), ("solution_vs_samp", t and t / solve["samp"]))
                        if v is not None})
        cells = ("-",) * 2 if s is None else (f"{1e3 * s:.2f}", f"{s / step['samp']:.2f}x")
        cells += ("-",) * 2 if t is None else (f"{t:.3f}", f"{t / solve['samp']:.2f}x")
        rows.append([name + (" (untrained)" if name in untrained else ""), *cells, "-" if ok is None else f"{ok:.0%}"])
    if untrained:  # rollouts of an untrained policy end at max_steps or a stall, not at the goal
        print(f"note: {', '.join(sorted(untrained))} untrained (default sizes; pass trained run folders with --runs): "
              "their step times hold, their solution times and solved shares do not; untrained MPNet does not plan, "
              "untrained SIMPNet plans with proposals that stand still")
    return metrics, [HEADER, *rows]
