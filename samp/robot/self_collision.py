"""Which pairs of a robot's collision links to leave out of self-collision checks (`self_collision_exclude`).

A pair is proposed for exclusion when its links are adjacent in the kinematic tree (joined directly or
through fixed joints only), touch at the home configuration (when a home is given), or touch in at least
`always` of random configurations within the limits: such links cannot be separated in practice, and a
check that counted them would call every configuration a collision. `python -m samp.robot add` uses this
to write a new robot's exclusions; `tools/self_collision_pairs.py` prints it for a configured robot.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field

import numpy as np

__all__ = ["ExclusionReport", "adjacent_pairs", "propose_exclusions"]


def adjacent_pairs(robot) -> set[frozenset]:
    """Collision links joined by exactly one movable joint or by fixed joints only (to their nearest
    collision-link ancestor)."""
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


@dataclass
class ExclusionReport:
    """The proposed exclusions and the sampled configurations they were drawn from.

    Attributes:
        rows: the excluded pairs, each [a, b] in `robot.link_names` order, sorted (the YAML's list).
        reasons: pair -> why it is excluded ("adjacent", "home", "always").
        share: pair -> the share of sampled configurations in which its links touch.
        samples: (N, n) the random configurations, radians.
        free: (N,) bool, the samples free of self-collision once the exclusions are left out.
    """

    rows: list[list[str]]
    reasons: dict[frozenset, list[str]]
    share: dict[frozenset, float]
    samples: np.ndarray
    free: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))


def propose_exclusions(robot, samples: int = 2000, always: float = 0.95, seed: int = 0, home=None,
                       progress: bool = False) -> ExclusionReport:
    """Propose `robot`'s self-collision exclusions from `samples` uniform configurations within its limits.

    Args:
        robot: a `samp.robot.Robot` (its configured exclusions are ignored).
        always: a pair touching in at least this share of the samples is excluded.
        home: (n,) a configuration whose touching pairs are excluded too (the configured home of an
            existing robot), or None (a new robot, whose home is chosen afterwards from `free`).
    """
    from samp.robot.bodies import LinkBodies

    lo, hi = robot.joint_limits.double().cpu().numpy().T
    qs = np.random.default_rng(seed).uniform(lo, hi, size=(samples, len(lo)))
    counts: Counter = Counter()
    hits = []  # per sample: the pairs in contact
    at_home: set[frozenset] = set()
    with LinkBodies(robot) as bodies:
        if home is not None:
            bodies.set_q(np.asarray(home, dtype=np.float64))
            at_home = {frozenset(p) for p in bodies.colliding_pairs()}
        rows = qs
        if progress:
            from tqdm import tqdm

            rows = tqdm(qs, desc=f"{robot.name}: random configurations")
        for q in rows:
            bodies.set_q(q)
            hits.append({frozenset(p) for p in bodies.colliding_pairs()})
            counts.update(hits[-1])
    adjacent = adjacent_pairs(robot)
    frequent = {p for p, c in counts.items() if c >= always * samples}
    excluded = adjacent | at_home | frequent
    order = {name: i for i, name in enumerate(robot.link_names)}
    rows_out = sorted((sorted(p, key=order.get) for p in excluded), key=lambda p: (order[p[0]], order[p[1]]))
    reasons = {p: [w for w, s in (("adjacent", adjacent), ("home", at_home), ("always", frequent)) if p in s]
               for p in excluded}
    return ExclusionReport(rows=rows_out, reasons=reasons, share={p: counts[p] / max(samples, 1) for p in excluded},
                           samples=qs, free=np.array([not (h - excluded) for h in hits], dtype=bool))
