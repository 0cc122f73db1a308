"""`RobotSDF`: the signed distance of a posed robot from a per-link network (docs/design.md section 4).

For a base-frame point p and configuration q, link i sees u_i = (T_i(q)^-1 p - c_i) / s_i, its point in
the link's normalised box. Its distance is

    d_i = s_i * f(u_i, i)                                  if u_i is in the box [-1, 1]^3,
    d_i = s_i * (max(f(clamp(u_i), i), 0) + |u_i - clamp(u_i)|)   otherwise (the out-of-box residual),

and the robot's distance is min_i d_i. The box surface lies outside the link (the box is padded), so
the clamped value is a distance and `max(., 0)` only guards a network that undershoots there; it also
makes s_i |u_i - clamp(u_i)| a lower bound of d_i. `query` uses that bound to skip pairs: it
evaluates the network on every in-box pair, then on each point's nearest box when the point is in no
box, then on the remaining pairs whose bound is below the best distance so far. The result is the
minimum over all pairs exactly; a policy batch (points within centimetres of the robot) touches only
the two or three links around each point.
"""

from __future__ import annotations

import torch
from torch import nn

from samp.robot_sdf.robot_points import SelfDistances

__all__ = ["RobotSDF"]

CHUNK = 1 << 15  # point-link pairs per network call: bounds the temporaries (larger was no faster on CPU)


class RobotSDF(nn.Module):
    """A posed robot's signed distance [m] from a link network `net(u, link)` (`samp.robot_sdf.model`).

    Args:
        robot: the `samp.robot.Robot` whose `link_names` the network was trained on, in that order.
        net: link network in normalised units.
        centres: (L, 3) link box centres in link frames [m]; scales: (L,) box half sides [m].
        method: a label for tables and recordings.
        meta: where the model came from (artifact path, dataset id, ...).
    """

    def __init__(self, robot, net: nn.Module, centres: torch.Tensor, scales: torch.Tensor, method: str = "",
                 meta: dict | None = None):
        super().__init__()
        n = len(robot.link_names)
        if tuple(centres.shape) != (n, 3) or tuple(scales.shape) != (n,):
            raise ValueError(f"centres and scales must be ({n}, 3) and ({n},) for {robot.name}'s {n} links, "
                             f"got {tuple(centres.shape)} and {tuple(scales.shape)}")
        self.robot, self.net, self.method, self.meta = robot, net, method, dict(meta or {})
        self.register_buffer("centres", centres.to(robot.dtype))
        self.register_buffer("scales", scales.to(robot.dtype))

    @property
    def link_names(self) -> list[str]:
        return self.robot.link_names

    def to(self, *args, **kwargs) -> "RobotSDF":
        """Move or cast everything, the robot's kinematic chain included (`Robot.to` moves it; the
        generic `nn.Module.to` would not), so use `.to(...)` rather than `.double()` / `.cuda()`."""
        super().to(*args, **kwargs)
        self.robot.to(*args, **kwargs)
        return self

    # ----------------------------------------------------------------- input checks
    def _check(self, points: torch.Tensor, q: torch.Tensor) -> None:
        dof = self.robot.dof
        if not isinstance(points, torch.Tensor) or not isinstance(q, torch.Tensor):
            raise TypeError(f"points and q must be torch tensors, got {type(points).__name__} and {type(q).__name__}")
        if points.ndim != 3 or points.shape[-1] != 3:
            hint = "; use points[None] for one configuration" if points.ndim == 2 and points.shape[-1] == 3 else ""
            raise ValueError(f"points must have shape (B, N, 3) in the robot's base frame, got {tuple(points.shape)}{hint}")
        if q.ndim != 2 or q.shape[1] != dof:
            raise ValueError(f"q must have shape (B, {dof}) for {self.robot.name}'s joints {self.robot.joint_names}, "
                             f"got {tuple(q.shape)}" + ("; use q[None] for one configuration" if q.ndim == 1 else ""))
        if q.shape[0] != points.shape[0]:
            raise ValueError(f"points and q must have the same batch size B, got {points.shape[0]} and {q.shape[0]}")
        if points.dtype != self.robot.dtype or q.dtype != self.robot.dtype:
            raise TypeError(f"points ({points.dtype}) and q ({q.dtype}) must have the model's dtype {self.robot.dtype}; "
                            f"convert them or call robot_sdf.to({points.dtype})")

    # ----------------------------------------------------------------- geometry
    def link_coords(self, points: torch.Tensor, q: torch.Tensor, poses: torch.Tensor | None = None) -> torch.Tensor:
        """(B, N, 3) base-frame points, (B, n) -> (B, N, L, 3) points in every link's normalised box.
        `poses`: the links' `robot.link_poses(q)`, when the caller has them already."""
        T = self.robot.link_poses(q) if poses is None else poses  # (B, L, 4, 4)
        (B, L), N = T.shape[:2], points.shape[1]
        R, t = T[..., :3, :3], T[..., :3, 3]
        # u_l = (R_l^T (p - t_l) - c_l) / s_l = p W_l + b_l, every link's box in one batched product over the
        # points: W_l = R_l / s_l (as row vectors, p R_l = (R_l^T p)^T) and b_l = -(t_l R_l + c_l) / s_l.
        W = (R / self.scales[:, None, None]).transpose(1, 2).reshape(B, 3, 3 * L)
        b = -((t[..., None, :] @ R)[..., 0, :] + self.centres) / self.scales[:, None]  # (B, L, 3)
        return torch.baddbmm(b.reshape(B, 1, 3 * L), points, W).view(B, N, L, 3)

    def _pair_values(self, u: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
        """(P, 3) normalised points, (P,) link -> (P,) distances [m] with the out-of-box residual."""
        inside = u.clamp(-1, 1)
        gap2 = (u - inside).square().sum(-1)
        outside = gap2 > 0
        # sqrt only where the gap is positive: its gradient at 0 would be NaN.
        gap = torch.where(outside, gap2.where(outside, torch.ones_like(gap2)).sqrt(), torch.zeros_like(gap2))
        f = torch.cat([self.net(inside[i:i + CHUNK], link[i:i + CHUNK]) for i in range(0, len(u), CHUNK)]) \
            if len(u) else u.new_zeros(0)
        return torch.where(outside, f.clamp(min=0) + gap, f) * self.scales[link]

    def local_distance(self, points: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
        """(P, 3) points in their own link frames, (P,) link index -> (P,) distance [m] to that link."""
        return self._pair_values((points - self.centres[link]) / self.scales[link, None], link)

    # ----------------------------------------------------------------- queries
    def link_distances(self, points: torch.Tensor, q: torch.Tensor) -> torch.Tensor:
        """(B, N, 3) base-frame points, q (B, n) -> (B, N, L) distance [m] to every link, all evaluated."""
        self._check(points, q)
        u = self.link_coords(points, q)
        B, N, L, _ = u.shape
        link = torch.arange(L, device=u.device).expand(B * N, L).reshape(-1)
        return self._pair_values(u.reshape(-1, 3), link).view(B, N, L)

    def query(self, points: torch.Tensor, q: torch.Tensor, cull: bool = True) -> torch.Tensor:
        """(B, N, 3) base-frame points, q (B, n) radians -> (B, N) signed distance [m] to the robot.

        Differentiable in points (and q). `cull=False` evaluates every point-link pair (same values).
        """
        if not cull:
            return self.link_distances(points, q).min(dim=-1).values
        self._check(points, q)
        u = self.link_coords(points, q)
        B, N, L, _ = u.shape
        u = u.reshape(B * N, L, 3)
        with torch.no_grad():
            bound = (u - u.clamp(-1, 1)).norm(dim=-1) * self.scales  # (BN, L) lower bounds [m]
        values = torch.full((B * N, L), float("inf"), dtype=u.dtype, device=u.device)
        done = bound == 0  # in-box pairs: always evaluated
        values = self._fill(values, u, done)
        best = values.detach().min(dim=1).values
        lonely = torch.isinf(best)  # in no box: start from the nearest box
        first = torch.zeros_like(done)
        first[lonely, bound[lonely].argmin(dim=1)] = True
        values = self._fill(values, u, first)
        best = values.detach().min(dim=1).values
        rest = ~(done | first) & (bound < best[:, None])
        values = self._fill(values, u, rest)
        return values.min(dim=1).values.view(B, N)

    def at_robot_points(self, q: torch.Tensor, points: torch.Tensor | None = None,
                        poses: torch.Tensor | None = None, tables: int = 0,
                        needed: torch.Tensor | bool | None = None) -> torch.Tensor:
        """q (B, n) -> (B, M) the robot SDF at the robot's own points posed at q, T_q(P): the values of
        `query(robot.transform_points(q), q)`, for a fraction of the work (`samp.robot_sdf.robot_points`).

        `points` and `poses` are `robot.transform_points(q)` and `robot.link_poses(q)` when the caller has
        them. `tables` K > 0 reads the pairs one joint apart from tables of K angles (an approximation of
        the network); 0 is exact. `needed` (B, M) bool: only those values are wanted (the others are upper
        bounds of theirs), e.g. where a loss term is active; False: at no point, so that only the pairs that
        the tables and the rigid part cover count (an approximation, `PolicySystem`'s robot_sdf_pairs=near).
        No gradients (the robot SDF is frozen wherever a policy uses it).
        """
        with torch.no_grad():
            poses = self.robot.link_poses(q) if poses is None else poses
            points = self.robot.transform_points(q, poses) if points is None else points
            self._check(points, q)
            return self.self_distances(tables).query(q, points, poses, needed)

    def self_distances(self, tables: int = 0):
        """The `SelfDistances` of these weights (built on first use, rebuilt when the weights, device or
        dtype change)."""
        key = (tables, self.centres.device, self.centres.dtype,
               *((t.data_ptr(), t._version) for t in [*self.net.parameters(), *self.net.buffers()]))
        cache = self.__dict__.setdefault("_self_distances", {})
        if cache.get(tables, (None,))[0] != key:
            with torch.inference_mode(False), torch.no_grad():  # plain tensors, usable in and out of inference mode
                cache[tables] = (key, SelfDistances(self, tables))
        return cache[tables][1]

    def _fill(self, values: torch.Tensor, u: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Evaluate the (BN, L) pairs selected by `mask` into `values` (out of place, for autograd)."""
        rows, cols = torch.nonzero(mask, as_tuple=True)
        if len(rows) == 0:
            return values
        return values.index_put((rows, cols), self._pair_values(u[rows, cols], cols))

    def extra_repr(self) -> str:
        return f"robot={self.robot.name}, method={self.method!r}, links={len(self.link_names)}"
