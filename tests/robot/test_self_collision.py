"""Self-collision exclusions: the home configuration is free, and only real neighbours are excluded."""

from __future__ import annotations

import numpy as np

from samp.sim import LinkBodies


def test_home_is_free_of_self_collision(robot):
    with LinkBodies(robot) as bodies:
        bodies.set_q(robot.home.numpy())
        hits = bodies.colliding_pairs(exclude=robot.self_collision_exclude)
    assert hits == [], f"{robot.name}: links in contact at home outside the exclusion list: {hits}"


def test_exclusions_are_kinematic_neighbours(robot):
    """Every excluded pair is a parent and child in the URDF tree (through fixed joints at most)."""
    urdf = robot.urdf

    def ancestors(link):
        out = []
        while (joint := urdf.parent_joint(link)) is not None:
            link = joint.parent
            out.append(link)
        return out

    for a, b in robot.self_collision_exclude:
        chain_ab = ancestors(b)[: ancestors(b).index(a) + 1] if a in ancestors(b) else None
        chain_ba = ancestors(a)[: ancestors(a).index(b) + 1] if b in ancestors(a) else None
        between = chain_ab or chain_ba
        assert between is not None, f"{robot.name}: excluded pair {a}-{b} is not parent and child"
        assert not set(between[:-1]) & set(robot.link_names), f"{robot.name}: {a}-{b} skips a collision link"


def test_a_folded_arm_collides_with_itself(robots):
    """The checker is not vacuous: the Panda's hand folded onto its base is reported."""
    robot = robots["panda"]
    q = np.array([0.0, 1.76, 0.0, -3.07, 0.0, 0.2, 0.0])  # shoulder down, elbow fully bent
    with LinkBodies(robot) as bodies:
        bodies.set_q(q)
        assert bodies.colliding_pairs(exclude=robot.self_collision_exclude), "expected a self-collision"
