"""Propose a robot's self-collision exclusion list (the `self_collision_exclude` of conf/robot/*.yaml).

The rule lives in `samp.robot.self_collision` (adjacent links, links touching at the configured home, and
links touching in at least `--always` of random configurations); `python -m samp.robot add` applies it to
a new robot. This prints it, with the reasons, for a robot that is already configured.

    python tools/self_collision_pairs.py panda [--samples 2000]
"""

from __future__ import annotations

import argparse

import yaml

from samp.robot import load_robot
from samp.robot.self_collision import propose_exclusions


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("robot")
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--always", type=float, default=0.95)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    robot = load_robot(args.robot)
    report = propose_exclusions(robot, args.samples, args.always, args.seed, home=robot.home.numpy(), progress=True)
    for a, b in report.rows:
        pair = frozenset((a, b))
        print(f"# {a} - {b}: {', '.join(report.reasons[pair])}; in contact in {report.share[pair]:.0%} of samples")
    print(f"# with these exclusions, {report.free.mean():.0%} of random configurations are free of self-collision")
    print(yaml.safe_dump({"self_collision_exclude": report.rows}, default_flow_style=None, width=110))


if __name__ == "__main__":
    main()
