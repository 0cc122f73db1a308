"""Propose a robot's self-collision exclusion list (the `self_collision_exclude` of conf/robot/*.yaml).

A pair of collision links is excluded when the links are adjacent in the kinematic tree (joined
directly or through fixed joints only), touch at the home configuration, or touch in at least
`--always` of random configurations within the limits (they cannot be separated in practice).

    python tools/self_collision_pairs.py panda [--samples 2000]
"""

from __future__ import annotations

import argparse
from collections import Counter

import numpy as np
import yaml
from tqdm import tqdm

from samp.robot import load_robot
from samp.robot.bodies import LinkBodies


def adjacent_pairs(robot) -> set[frozenset]:
    """Collision links joined by exactly one movable joint or by fixed joints only."""
    urdf, links = robot.urdf, set(robot.link_names)

    def moving_parent(link):  # nearest collision-link ancestor and the number of movable joints to it
        moves = 0
        while (joint := urdf.parent_joint(link)) is not None:
            moves += joint.type != "fixed"
            link = joint.parent
            if link in links:
                return link, moves
        return None, moves

    pairs = set()
    for link in links:
        parent, moves = moving_parent(link)
        if parent is not None and moves <= 1:
            pairs.add(frozenset((link, parent)))
    return pairs


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("robot")
    ap.add_argument("--samples", type=int, default=2000)
    ap.add_argument("--always", type=float, default=0.95)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args()
    robot = load_robot(args.robot)
    lo, hi = robot.joint_limits.double().numpy().T
    rng = np.random.default_rng(args.seed)
    counts: Counter = Counter()
    hits = []  # per sample: the pairs in contact
    with LinkBodies(robot) as bodies:
        bodies.set_q(robot.home.numpy())
        at_home = {frozenset(p) for p in bodies.colliding_pairs()}
        for _ in tqdm(range(args.samples), desc=f"{robot.name}: random configurations"):
            bodies.set_q(rng.uniform(lo, hi))
            hits.append({frozenset(p) for p in bodies.colliding_pairs()})
            counts.update(hits[-1])
    always = {p for p, c in counts.items() if c >= args.always * args.samples}
    excluded = adjacent_pairs(robot) | at_home | always
    order = {name: i for i, name in enumerate(robot.link_names)}
    rows = sorted((sorted(p, key=order.get) for p in excluded), key=lambda p: (order[p[0]], order[p[1]]))
    for p in rows:
        why = [w for w, s in (("adjacent", adjacent_pairs(robot)), ("home", at_home), ("always", always)) if frozenset(p) in s]
        print(f"# {p[0]} - {p[1]}: {', '.join(why)}; in contact in {counts[frozenset(p)] / args.samples:.0%} of samples")
    free = sum(not (h - excluded) for h in hits)
    print(f"# with these exclusions, {free / args.samples:.0%} of random configurations are free of self-collision")
    print(yaml.safe_dump({"self_collision_exclude": rows}, default_flow_style=None, width=110))


if __name__ == "__main__":
    main()
