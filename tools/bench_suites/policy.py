"""`policy` suite: one SAMP policy step at B = 1, stage by stage, against the generic exact path as the
baseline, the batched step's throughput, and training samples per second; peak memory.

Networks: --policy-run RUN_DIR's trained policy at its own n_e, else untrained networks of two sizes: the
quickstart network (half-width PointNet, the small robot SDF) at the first --anchors n_e and the paper-width
network (the default robot SDF) at the others. An untrained robot SDF answers near 0 everywhere, which makes
its pair culling look cheaper than a trained one's: give --robot-sdf ARTIFACT (a trained robot_sdf.pt) for
step times that hold. Stages of a step (`_stages`): FK of the links, posing the robot points, the robot SDF
at them (tables, and the exact network for comparison), sampling the scene's feature volume, the PointNet,
the other MLPs; "other" is the rest of the step call (normalisation, argument passing, Python).

--baseline-src DIR (an older checkout) times, each in its own process in the same run: with --policy-run, that
policy's B = 1 step (`rollout_step.py`); with --robot-sdf, a training step (`train_step.py`).

Reads --anchors (added by the scene suite), --policy-run (eval suite), --baseline-src (data suite); adds --robot-sdf
and --tables.
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch

from samp.data.binding import DatasetBinding

from .common import HEADER, timeit, untrained_policy_system

B = 50  # training batch size
B_BATCHED = 100  # rollout batch of the evaluation


def add_arguments(ap: argparse.ArgumentParser) -> None:
    ap.add_argument("--robot-sdf", help="policy: a trained robot SDF artifact for the untrained policy networks")
    ap.add_argument("--tables", type=int, default=None,
                    help="policy: joint angles per robot-SDF table (0: exact; default: the system's own)")


def _median_ms(fn, repeats: int = 50) -> float:
    """Median wall milliseconds of single calls (one call is what a rollout step pays)."""
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return 1e3 * statistics.median(times)


def _stages(system, q, q_goal, features, scene, bounds) -> dict[str, float]:
    """Milliseconds of each stage of one step at B = len(q) on the torch path ("other": the rest of its step
    call), of that whole step ("step, torch path"), and of the default `SAMPStepPolicy` step ("step"): on a CPU
    with near pairs, the compiled inputs ("compiled inputs") and the learned layers after them."""
    from samp.policy.compiled import compiled_step_available
    from samp.policy.network import goal_features, max_over_points, normalize, sample_by_scene
    from samp.policy.step import SAMPStepPolicy

    robot, rsdf, net, tables = system.robot, system.robot_sdf, system.net, system.robot_sdf_tables
    needed = False if system.robot_sdf_pairs == "near" else None
    with torch.inference_mode():
        poses = robot.link_poses(q)
        points = robot.transform_points(q, poses)
        d = rsdf.at_robot_points(q, points, poses, tables, needed)
        u_t, u_g = normalize(q, system.limits), normalize(q_goal, system.limits)
        box = net.env.feature_bounds(bounds, system.n_e, features.shape[-1])
        env = sample_by_scene(features, scene, points, box).transpose(1, 2)
        n = len(q)
        width = net.fusion[0].in_features
        parts = {
            "fk (link poses)": _median_ms(lambda: robot.link_poses(q)),
            "robot points": _median_ms(lambda: robot.transform_points(q, poses)),
            "robot SDF": _median_ms(lambda: rsdf.at_robot_points(q, points, poses, tables, needed)),
            "feature sampling": _median_ms(lambda: sample_by_scene(features, scene, points, box)),
            "PointNet": _median_ms(lambda: max_over_points(net.point_mlp, torch.cat([points, d[..., None]], dim=-1))),
            "MLPs": _median_ms(lambda: (net.env_mlp(torch.cat([env, d[..., None]], dim=-1).reshape(n, -1)),
                                        net.config_mlp(goal_features(u_t, u_g, net.cfg.goal_features)),
                                        net.fusion(q.new_zeros(n, width)))),
        }
        every = (_median_ms(lambda: rsdf.at_robot_points(q, points, poses, tables)) if needed is False
                 else parts["robot SDF"])
        exact = _median_ms(lambda: rsdf.at_robot_points(q, points, poses, 0)) if tables else parts["robot SDF"]
    plain = SAMPStepPolicy(system, compiled=False)
    env_batch = _env(system, features.shape[0], scene)
    plain.reset(env_batch)
    torch_step = _median_ms(lambda: plain.step(q, q_goal, env_batch))
    out = {**parts, "other": torch_step - sum(parts.values()), "step, torch path": torch_step,
           "robot SDF all pairs": every, "robot SDF exact": exact, "step": torch_step}
    if compiled_step_available(system):  # the default step on a CPU: the inputs in one compiled call, then the head
        policy = SAMPStepPolicy(system)
        policy.reset(env_batch)
        inputs = policy._inputs(q, q_goal, scene)
        with torch.inference_mode():
            out["compiled inputs"] = _median_ms(lambda: policy._inputs(q, q_goal, scene))
            out["learned layers (SAMPNet.head)"] = _median_ms(lambda: net.head(*inputs))
        out["step"] = _median_ms(lambda: policy.step(q, q_goal, env_batch))
    return out


def _env(system, scenes: int, scene_index: torch.Tensor):
    from samp.policy.interface import EnvBatch

    bounds = torch.tensor([system.bounds] * scenes, dtype=system.robot.dtype, device=system.device)
    return EnvBatch(system.grids[:scenes], bounds, scene_index)


def _generic_step_ms(system, q, q_goal, features, scene, bounds) -> float:
    """The baseline: the same step through the general APIs (FK of every frame, the robot SDF's culled query
    of arbitrary points), as a policy step was computed before the robot-point specialisations."""
    from samp.policy.network import denormalize, normalize

    robot, rsdf = system.robot, system.robot_sdf

    def step():
        points = robot.transform_points(q)
        fk = robot.fk(q)  # the query's own FK of every link
        torch.stack([fk[name] for name in rsdf.link_names], dim=1)
        d = rsdf.query(points, q)
        u = system.net(normalize(q, system.limits), normalize(q_goal, system.limits), points, d, features, scene, bounds,
                       n_e=system.n_e)
        return denormalize(u, system.limits)

    with torch.inference_mode():
        return _median_ms(step, repeats=20)


def _systems(args, device) -> list[tuple[str, object, int]]:
    """(label, system, n_e) to time: the trained run, or the untrained quickstart and paper-width networks."""
    from samp.robot import load_robot

    if args.policy_run:
        from samp.policy import load_system
        from samp.paths import find_checkpoint

        system = load_system(find_checkpoint(args.policy_run)).to(device)
        return [(f"trained ({args.policy_run})", system, system.n_e)]
    robot = load_robot(args.robot)
    out = []
    for i, n_e in enumerate(args.anchors):
        quick = i == 0
        model = {"point_hidden": [32, 64, 128]} if quick else {}
        system = untrained_policy_system(robot, args.robot, "robot_sdf_hash_small" if quick else "robot_sdf_hash",
                                         model=model, artifact=args.robot_sdf).to(device)
        out.append((f"{'quickstart' if quick else 'paper'}-width network", system, n_e))
    return out


def train_step(system, robot, g: torch.Generator, device: torch.device, batch_size: int = B):
    """One training step of `batch_size` random configurations (forward, losses, backward, the optimizer training
    uses, without its scheduler) as a callable of the batch's scene indices (batch_size,); the system's bound grids.
    Also the `paper` suite's step."""
    lo, hi = robot.joint_limits.float().T
    q = (lo + (hi - lo) * torch.rand(batch_size, robot.dof, generator=g)).to(device)
    batch = {"q": q, "q_next": q + 0.01, "q_goal": q.flip(0)}
    configured = system.configure_optimizers()
    opt = configured["optimizer"] if isinstance(configured, dict) else configured

    def step(scene):
        loss = system._losses({**batch, "scene": scene})["loss"]
        opt.zero_grad()
        loss.backward()
        opt.step()

    return step


def _time_training(system, robot, scenes: list, g: torch.Generator, device: torch.device) -> tuple[float, float]:
    """Seconds per training step of B samples: scene-grouped (2 scenes) and random (~8 scenes) batches."""
    step = train_step(system, robot, g, device)
    system.train()
    grouped = torch.arange(B, device=device) * 2 // B  # 2 scenes
    plain = torch.randint(0, len(scenes), (B,), generator=g).to(device)  # ~8 scenes
    t_grouped = timeit(lambda: step(grouped), device, min_time=0.0, repeats=3)
    t_plain = timeit(lambda: step(plain), device, min_time=0.0, repeats=3)
    system.eval()
    return t_grouped, t_plain


def _in_process(script: str, src: str, *extra: str) -> dict:
    """`script` (beside this file) run with `src`'s samp in a fresh process (its result line, parsed)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    out = subprocess.run([sys.executable, str(Path(__file__).with_name(script)), "--src", src, *extra],
                         capture_output=True, text=True)
    if out.returncode:
        raise RuntimeError(f"{script} with {src} failed:\n{out.stderr[-2000:]}")
    return json.loads(out.stdout.strip().splitlines()[-1])


def _step_in_process(src: str, args, *extra: str) -> dict:
    """A training step of `src`'s samp (`train_step.py`)."""
    return _in_process("train_step.py", src, "--robot-sdf", args.robot_sdf, "--n-e", str(args.anchors[0]), *extra)


def _rollout_against_checkout(args, metrics: dict) -> list[list]:
    """The --policy-run policy's B = 1 step and a step of 100 problems with this checkout against
    --baseline-src, each in its own process, alternately three times (`rollout_step.py`; the fastest of
    each), and the largest difference between their first predictions (0 for a change that is exact)."""
    from pathlib import Path

    here = str(Path(__file__).resolve().parents[2])
    runs = {src: [] for src in (here, str(args.baseline_src))}
    for _ in range(3):
        for src in runs:
            runs[src].append(_in_process("rollout_step.py", src, "--run", str(args.policy_run)))
    new, old = ({"step_ms": min(x["step_ms"] for x in r), "batch_ms": min(x["batch_ms"] for x in r),
                 "threads": r[0]["threads"], "q_next": r[0]["q_next"]} for r in runs.values())
    diff = max(abs(a - b) for a, b in zip(new["q_next"], old["q_next"]))
    metrics.update({"checkout/step_b1_ms": new["step_ms"], "checkout/baseline_step_b1_ms": old["step_ms"],
                    "checkout/step_speedup": old["step_ms"] / new["step_ms"], "checkout/q_next_max_diff": diff,
                    "checkout/step_b100_ms": new["batch_ms"], "checkout/baseline_step_b100_ms": old["batch_ms"]})
    return [[f"step B=1 ({new['threads']} threads), vs {args.baseline_src}", f"{new['step_ms']:.2f} ms",
             f"{old['step_ms']:.2f} ms", f"{old['step_ms'] / new['step_ms']:.2f}x"],
            [f"step B=100 (one call), vs {args.baseline_src}", f"{new['batch_ms']:.1f} ms", f"{old['batch_ms']:.1f} ms",
             f"{old['batch_ms'] / new['batch_ms']:.2f}x"],
            ["  largest difference of the first predictions", f"{diff:.1e} rad", "", ""]]


# Alternating rounds of the training step against --baseline-src: one process each per round, so a slow
# spell of the machine falls on both checkouts; the ratio reported is the median of the rounds' ratios.
ROUNDS = 3


def _against_checkout(args, metrics: dict) -> list[list]:
    """Training samples per second of the quickstart network at B = 50, this checkout against
    --baseline-src, each in its own process, alternately for `ROUNDS` rounds in this run; and this checkout's
    step at the older settings (exact robot SDF at every pair, bounds registration, BatchNorm), timed too,
    whose loss on the same batch must match."""
    from pathlib import Path

    if not args.robot_sdf:
        raise SystemExit("--baseline-src needs --robot-sdf ARTIFACT (a trained robot_sdf.pt): an untrained robot SDF "
                         "culls pairs unlike a trained one")
    here = str(Path(__file__).resolve().parents[2])
    rounds = [(_step_in_process(here, args), _step_in_process(str(args.baseline_src), args)) for _ in range(ROUNDS)]
    exact = _step_in_process(here, args, "--exact")

    def median(side: int, key: str) -> float:  # side 0: this checkout, 1: the baseline
        return statistics.median(r[side][key] for r in rounds)

    ratios = [o["seconds_per_step"] / n["seconds_per_step"] for n, o in rounds]
    cpu_ratios = [o["cpu_seconds_per_step"] / n["cpu_seconds_per_step"] for n, o in rounds]
    new_s, old_s = median(0, "seconds_per_step"), median(1, "seconds_per_step")
    new, old = rounds[0]  # the losses and thread count (the same in every round)
    key = f"n{args.anchors[0]}/checkout"
    metrics.update({f"{key}/train_samples_per_s": B / new_s, f"{key}/baseline_train_samples_per_s": B / old_s,
                    f"{key}/train_speedup": statistics.median(ratios),
                    **{f"{key}/train_speedup_round{i}": r for i, r in enumerate(ratios)},
                    f"{key}/train_cpu_speedup": statistics.median(cpu_ratios),
                    f"{key}/exact_settings_train_speedup": old_s / exact["seconds_per_step"],
                    f"{key}/loss": new["loss"], f"{key}/loss_exact_settings": exact["loss"],
                    f"{key}/baseline_loss": old["loss"]})
    rel = abs(exact["loss"] - old["loss"]) / abs(old["loss"])
    return [[f"train step B={B}, n_e={args.anchors[0]} ({new['threads']} threads), vs {args.baseline_src}: median of "
             f"{ROUNDS} alternating rounds", f"{B / new_s:.0f} samples/s", f"{B / old_s:.0f} samples/s",
             f"{statistics.median(ratios):.2f}x"],
            ["  each round's ratio", "", "", " ".join(f"{r:.2f}x" for r in ratios)],
            ["  CPU seconds per step", f"{median(0, 'cpu_seconds_per_step'):.3f} s",
             f"{median(1, 'cpu_seconds_per_step'):.3f} s", f"{statistics.median(cpu_ratios):.2f}x"],
            ["  at the older settings (exact robot SDF, all pairs, BatchNorm, bounds)",
             f"{B / exact['seconds_per_step']:.0f} samples/s", f"{B / old_s:.0f} samples/s",
             f"{old_s / exact['seconds_per_step']:.2f}x"],
            ["  loss on the same batch (older settings / defaults)", f"{exact['loss']:.7f} / {new['loss']:.7f}",
             f"{old['loss']:.7f}", f"rel. diff {rel:.1e}"]]


def run(args) -> tuple[dict, list[list]]:
    """Per configuration: the step's stages at B = 1, the step against the generic path, the batched step, and
    (untrained networks only) training samples per second, scene-grouped against random batches."""
    import resource

    from samp.scene import generate_scene

    device = torch.device(args.device)
    g = torch.Generator().manual_seed(0)
    scenes = [generate_scene(["tabletop", "shelf", "cabinet", "blocks"][i % 4], seed=i) for i in range(8)]
    metrics, rows = {}, []
    for label, system, n_e in _systems(args, device):
        robot = system.robot
        if args.tables is not None:
            system.planner(robot_sdf_tables=args.tables)  # sets the tables, and the pairs they allow (0: exact)
        grids = torch.stack([s.anchor_grid(n_e) for s in scenes])
        if system.binding is None or system.grids is None:
            bounds = system.bounds or scenes[0].bounds
            system.bind(DatasetBinding(robot.name, robot.asset_hash, "bench", n_e, bounds, grids))
        system.eval()
        lo, hi = robot.joint_limits.float().T
        qs = (lo + (hi - lo) * torch.rand(B_BATCHED + 1, robot.dof, generator=g)).to(device)
        q, q_goal = qs[:1], qs[1:2]
        with torch.inference_mode():
            features = system.encode(system.grids[:1])
            feats_all = system.encode(system.grids)
        zero = torch.zeros(1, dtype=torch.long, device=device)
        key = f"n{n_e}"
        stages = _stages(system, q, q_goal, features, zero, system.bounds)
        generic = _generic_step_ms(system, q, q_goal, features, zero, system.bounds)
        many = torch.arange(B_BATCHED, device=device) % len(scenes)
        batch_stages = _stages(system, qs[:B_BATCHED], qs[1:], feats_all, many, system.bounds)
        batched, batched_torch = batch_stages["step"], batch_stages["step, torch path"]
        metrics.update({f"{key}/step_b1_ms": stages["step"], f"{key}/generic_step_b1_ms": generic,
                        f"{key}/step_speedup": generic / stages["step"], f"{key}/step_b{B_BATCHED}_ms": batched,
                        f"{key}/step_b{B_BATCHED}_torch_path_ms": batched_torch,
                        f"{key}/batched_steps_per_s": B_BATCHED * 1e3 / batched,
                        f"{key}/robot_sdf_tables": system.robot_sdf_tables,
                        f"{key}/robot_sdf_pairs": system.robot_sdf_pairs,
                        **{f"{key}/stage/{k}_ms": v for k, v in stages.items()}})
        rows.append([f"{label}, n_e={n_e}: step B=1", f"{stages['step']:.2f} ms", f"{generic:.2f} ms (generic)",
                     f"{generic / stages['step']:.1f}x"])
        for k, v in stages.items():
            if k == "step, torch path":
                rows.append([f"  {k} (compiled=False; the stages above are its)", f"{v:.3f} ms", "",
                             f"{v / stages['step']:.2f}x"])
            elif k != "step":
                rows.append([f"  {k}" + (f" (tables K={system.robot_sdf_tables}, {system.robot_sdf_pairs} pairs)"
                                         if k == "robot SDF" else ""),
                             f"{v:.3f} ms", "", ""])
        rows.append([f"  step B={B_BATCHED} (one call, {len(scenes)} scenes)", f"{batched:.1f} ms",
                     f"{B_BATCHED * 1e3 / batched:.0f} problem-steps/s",
                     f"{batched_torch:.1f} ms torch path"])
        if not args.policy_run:
            t_grouped, t_plain = _time_training(system, robot, scenes, g, device)
            metrics.update({f"{key}/train_samples_per_s": B / t_grouped, f"{key}/train_samples_per_s_random": B / t_plain,
                            f"{key}/grouped_speedup": t_plain / t_grouped})
            rows.append([f"  train (B={B})", f"{B / t_grouped:.0f} samples/s", f"{B / t_plain:.0f} samples/s (random)",
                         f"{t_plain / t_grouped:.2f}x"])
    if args.baseline_src and args.policy_run:
        rows += _rollout_against_checkout(args, metrics)
    if args.baseline_src and (args.robot_sdf or not args.policy_run):
        rows += _against_checkout(args, metrics)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    metrics["peak_rss_mb"] = peak
    if device.type == "cuda":
        metrics["peak_cuda_mb"] = torch.cuda.max_memory_allocated(device) / 2**20
    rows.append(["peak memory (process RSS)", f"{peak:.0f} MB", "", ""])
    return metrics, [HEADER, *rows]
