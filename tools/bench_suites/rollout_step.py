"""One policy step at B = 1, timed, in a process of its own: `python tools/bench_suites/rollout_step.py --src DIR
--run RUN_DIR` prints JSON {"step_ms", "step_ms_median", "batch_ms", "threads", "q_next"} for the samp package found
in DIR.

The policy suite runs it with this checkout and with --baseline-src (an older checkout, e.g. a `git worktree`
of the commit to compare against), alternately, so both are timed in the same run on the same problems,
through the API both share: load_policy(run), plan's scene-to-environment step, reset and step. `step_ms` is
the fastest of several blocks of 20 steps (per step): the least disturbed by other work on the machine;
`batch_ms` is the fastest of ten calls stepping 100 problems at once (one scene); `q_next` (the first problem's
prediction) shows whether the two checkouts compute the same step.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time


def main(argv=None) -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--src", required=True, help="the checkout whose samp is timed")
    ap.add_argument("--run", required=True, help="a trained SAMP policy run folder")
    ap.add_argument("--blocks", type=int, default=20, help="blocks of 20 steps")
    args = ap.parse_args(argv)
    sys.path.insert(0, args.src)

    import torch

    from samp.policy import load_policy
    from samp.scene import generate_scene

    policy = load_policy(args.run, device="cpu")
    env = policy._environment(generate_scene("shelf", seed=7, bounds=policy.system.bounds))
    policy.reset(env)
    lo, hi = policy.robot.joint_limits.to(policy.robot.dtype).T
    qs = lo + (hi - lo) * torch.rand(21, policy.robot.dof, generator=torch.Generator().manual_seed(0),
                                     dtype=policy.robot.dtype)
    first = policy.step(qs[:1], qs[1:2], env)
    blocks = []
    for _ in range(args.blocks):
        t0 = time.perf_counter()
        for i in range(20):
            policy.step(qs[i:i + 1], qs[i + 1:i + 2], env)
        blocks.append((time.perf_counter() - t0) / 20 * 1e3)
    from samp.policy.interface import EnvBatch

    many = lo + (hi - lo) * torch.rand(101, policy.robot.dof, generator=torch.Generator().manual_seed(1),
                                       dtype=policy.robot.dtype)
    batch_env = EnvBatch(env.grids, env.bounds, torch.zeros(100, dtype=torch.long))
    policy.reset(batch_env)
    batched = []
    for _ in range(11):
        t0 = time.perf_counter()
        policy.step(many[:100], many[1:], batch_env)
        batched.append((time.perf_counter() - t0) * 1e3)
    print(json.dumps({"step_ms": min(blocks), "step_ms_median": statistics.median(blocks), "batch_ms": min(batched[1:]),
                      "threads": torch.get_num_threads(), "q_next": first[0].tolist()}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
