"""The robot SDF at the robot's own points, T_q(P), as a policy step needs it (docs/design.md section 4).

A robot point is fixed in its own link's frame, so how far it is from a link depends only on the joints
between the two links. `SelfDistances` sorts every (point, link) pair by that count once:

* **rigid** pairs (no arm joint between: the point's own link, and e.g. the Panda's hand and fingers for
  a point on link 7) never change: their network values are computed once and their minimum is the
  starting value of every query;
* **one-joint** pairs (a point and the next link along the chain) depend on that joint's angle alone;
* the rest depend on two joints or more.

`query` starts from the rigid minimum and lowers it with the other pairs. A pair goes through the
network only when its box bound (`RobotSDF`'s out-of-box lower bound) is below the value so far or the
point is inside its box; the others cannot lower the minimum, so the result is the minimum over all
pairs, as `RobotSDF.query` computes it, exactly. With `samples` K > 0, one-joint pairs are instead read
from a table of the network's values at K angles over the joint's range (linear interpolation): an
approximation of the network, not of the robot, built once per set of weights (about 1 s on a CPU) and
measured against the exact path in `tools/bench.py policy`.
"""

from __future__ import annotations

import torch

__all__ = ["SelfDistances"]

# A one-joint pair is left out of the tables when its box bound stays above the rigid minimum by this margin [m]
# plus how far a point can move between two tabulated angles (_REACH times the step, radians) at every angle.
_TABLE_MARGIN = 0.02
_REACH = 0.5  # m: no robot point is farther than this from the joint that moves it relative to the next link


def _arm_joints_between(robot, a: str, b: str) -> list[int]:
    """Indices (into `robot.joint_names`) of the arm joints on the kinematic path between links a and b."""
    def chain(link: str) -> list[str]:
        joints = []
        while (joint := robot.urdf.parent_joint(link)) is not None:
            joints.append(joint.name)
            link = joint.parent
        return joints

    ja, jb = chain(a), chain(b)
    between = set(ja) ^ set(jb)
    return sorted(robot.joint_names.index(j) for j in between if j in robot.joint_names)


class SelfDistances:
    """The pieces of the robot SDF at the robot points that do not depend on q, for one `RobotSDF`.

    Args:
        sdf: the `RobotSDF` (its robot's points, links and network).
        samples: K angles per one-joint table; 0 evaluates those pairs with the network (exact).
    """

    def __init__(self, sdf, samples: int = 0):
        if samples < 0 or samples == 1:
            raise ValueError(f"samples must be 0 (exact) or >= 2 angles per table, got {samples}")
        robot = sdf.robot
        self.sdf, self.samples = sdf, samples
        own = robot.point_collision_links  # (M,)
        M, L = len(own), len(robot.link_names)
        device = own.device
        joints = [[_arm_joints_between(robot, robot.link_names[i], robot.link_names[k]) for k in range(L)]
                  for i in range(L)]
        # Rigid pairs: their minimum, once, at the home configuration (any q gives the same values).
        home = robot.home.to(robot.dtype)[None]
        u_home = sdf.link_coords(robot.transform_points(home), home)[0]  # (M, L, 3)
        rigid = torch.tensor([[len(joints[i][k]) == 0 for k in range(L)] for i in range(L)], device=device)[own]  # (M, L)
        m, l = torch.nonzero(rigid, as_tuple=True)
        base = torch.full((M,), float("inf"), dtype=robot.dtype, device=device)
        base.scatter_reduce_(0, m, sdf._pair_values(u_home[m, l], l), "amin")
        self.base = base
        # One-joint pairs: tabulated (samples > 0) or evaluated as the others.
        single = torch.tensor([[len(joints[i][k]) == 1 for k in range(L)] for i in range(L)], device=device)[own]
        self.table = None
        if samples:
            self._tabulate(single, joints)
            self.network_pairs = ~rigid & ~single  # (M, L)
        else:
            self.network_pairs = ~rigid

    def _tabulate(self, single: torch.Tensor, joints: list) -> None:
        """Network values of every one-joint pair that can lower the minimum, at `samples` angles."""
        sdf, robot, K = self.sdf, self.sdf.robot, self.samples
        own = robot.point_collision_links
        m, l = torch.nonzero(single, as_tuple=True)
        joint = torch.tensor([joints[a][b][0] for a, b in zip(own[m].tolist(), l.tolist())], device=m.device)
        lo, hi = robot.joint_limits.to(robot.dtype).T  # (n,), (n,)
        # Configuration k has every joint at its k-th angle: each pair sees its own joint's k-th sample.
        q = lo + (hi - lo) * torch.linspace(0, 1, K, dtype=robot.dtype, device=m.device)[:, None]  # (K, n)
        u = torch.cat([sdf.link_coords(robot.transform_points(c), c)[:, m, l] for c in q.split(64)])  # (K, P, 3)
        bound = (u - u.clamp(-1, 1)).norm(dim=-1) * sdf.scales[l]  # (K, P)
        step = float(((hi - lo) / (K - 1)).max())
        keep = (bound < self.base[m] + _TABLE_MARGIN + _REACH * step).any(dim=0)
        m, l, joint, u = m[keep], l[keep], joint[keep], u[:, keep].transpose(0, 1)  # u: (P, K, 3)
        values = sdf._pair_values(u.reshape(-1, 3), l.repeat_interleave(K)).view(-1, K)
        self.table, self.table_point, self.table_joint = values.contiguous(), m, joint
        self.table_row_start = torch.arange(len(m), device=m.device) * K  # where each table starts in the flat view
        self.table_lo, self.table_span = lo[joint], (hi - lo)[joint]

    def query(self, q: torch.Tensor, points: torch.Tensor, poses: torch.Tensor,
              needed: torch.Tensor | bool | None = None) -> torch.Tensor:
        """q (B, n), T_q(P) (B, M, 3) and `robot.link_poses(q)` -> (B, M) distances [m], no gradients.
        `needed` (B, M) bool: the network pairs are evaluated at those points only; elsewhere the result is
        the rigid and table part, an upper bound of the distance. `needed=False`: at no point (the rigid
        and table part everywhere)."""
        sdf, M = self.sdf, len(self.base)
        B = len(q)
        out = self.base.repeat(B, 1)  # a copy: the scatters below must not touch the cached values
        if self.table is not None and len(self.table_point):
            offset = torch.arange(B, device=q.device)[:, None] * M  # flat (b, m) index = b * M + m
            t = ((q[:, self.table_joint] - self.table_lo) / self.table_span).clamp(0, 1) * (self.samples - 1)  # (B, P)
            i = t.nan_to_num(0).floor().clamp(max=self.samples - 2).long()
            f = t - i  # NaN where q is: the value becomes NaN too, as the network's would
            flat = self.table.view(-1)  # one flat index (row * K + i) gathers faster than a (row, i) pair
            at = i + self.table_row_start
            v = flat[at] * (1 - f) + flat[at + 1] * f
            out.view(-1).scatter_reduce_(0, (offset + self.table_point).view(-1), v.view(-1), "amin")
        if needed is None:
            u = sdf.link_coords(points, q, poses)  # (B, M, L, 3)
            bound = (u - u.clamp(-1, 1)).norm(dim=-1) * sdf.scales  # (B, M, L)
            b, m, l = torch.nonzero(self.network_pairs & ((bound < out[:, :, None]) | (bound == 0)), as_tuple=True)
            if len(b):
                out.view(-1).scatter_reduce_(0, b * M + m, sdf._pair_values(u[b, m, l], l), "amin")
        elif needed is not False:  # the same, for the needed points only (their coordinates are the full query's)
            rb, rm = torch.nonzero(needed, as_tuple=True)
            u = sdf.link_coords(points, q, poses)[rb, rm]  # (R, L, 3): one batched product is cheap at any B
            bound = (u - u.clamp(-1, 1)).norm(dim=-1) * sdf.scales  # (R, L)
            r, l = torch.nonzero(self.network_pairs[rm] & ((bound < out[rb, rm][:, None]) | (bound == 0)),
                                 as_tuple=True)
            if len(r):
                out.view(-1).scatter_reduce_(0, rb[r] * M + rm[r], sdf._pair_values(u[r, l], l), "amin")
        return out.masked_fill(q.isnan().any(dim=-1, keepdim=True), float("nan"))  # an undefined robot: no distances
