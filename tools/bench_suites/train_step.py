"""One SAMP training step, timed, in a process of its own: `python tools/bench_suites/train_step.py --src DIR ...`
prints JSON {"seconds_per_step", "cpu_seconds_per_step", "loss", "threads"} for the samp package found in DIR.

The policy suite runs it once with this checkout and once with --baseline-src (an older checkout, e.g. a
`git worktree` of the commit to compare against), so both are timed in the same run, on the same batch,
through the API both versions share: PolicySystem(robot, robot_sdf_payload, model), bind(DatasetBinding),
_losses(batch) and configure_optimizers (each checkout's own optimizer). `--exact` asks for the settings an
older checkout had (the robot SDF evaluated at every pair, features read over the grid's bounds, BatchNorm in
the env encoder), to compare the loss on the fixed batch.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time


def _optimizer(system):
    """The optimizer the checkout's own training would use (`configure_optimizers`, without its scheduler)."""
    configured = system.configure_optimizers()
    return configured["optimizer"] if isinstance(configured, dict) else configured


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--src", required=True, help="the checkout whose samp is timed")
    ap.add_argument("--robot-sdf", required=True, help="a trained robot_sdf.pt")
    ap.add_argument("--n-e", type=int, default=40)
    ap.add_argument("--point-hidden", default="32,64,128", help="PointNet widths (the quickstart network's)")
    ap.add_argument("--batch", type=int, default=50)
    ap.add_argument("--steps", type=int, default=30)  # the median of 30: this shared machine's rate moves
    ap.add_argument("--exact", action="store_true", help="exact robot SDF and bounds registration (older code's)")
    args = ap.parse_args(argv)
    sys.path.insert(0, args.src)

    import torch

    from samp.data.binding import DatasetBinding
    from samp.policy.system import PolicySystem, read_robot_sdf
    from samp.scene import generate_scene

    model = {"point_hidden": [int(w) for w in args.point_hidden.split(",")]}
    extra = {}
    if args.exact:
        try:
            PolicySystem.__init__.__code__.co_varnames.index("robot_sdf_tables")
            model["registration"], extra["robot_sdf_tables"] = "bounds", 0
        except ValueError:  # a checkout from before tables and registration: it is exact already
            pass
        from dataclasses import fields

        from samp.policy.network import PolicyConfig

        if "norm" in {f.name for f in fields(PolicyConfig)}:  # BatchNorm was the only normalisation before
            model["norm"] = "batch"
    torch.manual_seed(0)
    system = PolicySystem(robot="panda", robot_sdf_payload=read_robot_sdf(args.robot_sdf), model=model, **extra)
    robot = system.robot
    scenes = [generate_scene(["tabletop", "shelf", "cabinet", "blocks"][i % 4], seed=i) for i in range(4)]
    grids = torch.stack([s.anchor_grid(args.n_e) for s in scenes])
    system.bind(DatasetBinding(robot.name, robot.asset_hash, "bench", args.n_e, scenes[0].bounds, grids))
    g = torch.Generator().manual_seed(0)
    lo, hi = robot.joint_limits.float().T
    q = lo + (hi - lo) * torch.rand(args.batch, robot.dof, generator=g)
    # Near the demonstrations' clearance: the next configuration a small step away, two scenes per batch.
    batch = {"q": q, "q_next": q + 0.01, "q_goal": q.flip(0), "scene": torch.arange(args.batch) * 2 // args.batch}
    system.train()
    with torch.no_grad():
        loss = float(system._losses(batch)["loss"])
    opt = _optimizer(system)

    def step():
        out = system._losses(batch)["loss"]
        opt.zero_grad()
        out.backward()
        opt.step()

    step()
    times, cpu = [], []
    for _ in range(args.steps):
        t0, c0 = time.perf_counter(), time.process_time()
        step()
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    print(json.dumps({"seconds_per_step": statistics.median(times), "cpu_seconds_per_step": statistics.median(cpu),
                      "loss": loss, "threads": torch.get_num_threads()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
