"""What a SAMP policy step feeds its network, computed in one compiled call (numba) for rollouts on a CPU.

At B = 1 a step in torch is about fifty small operations before the network's products (forward kinematics,
posing the 1024 robot points, the robot SDF's tables, grid sampling, normalisation, concatenations), each
paying torch's per-call overhead: 0.7 to 0.8 ms of a 2.3 ms step on a 2-core CPU. `StepInputs` computes the
same inputs in one pass of compiled loops:

* the robot points posed at q: the serial arm's link poses (`samp.sim.broadphase.serial_link_poses`, float64)
  applied to each point in its link's frame;
* the robot SDF there as `robot_sdf_pairs=near` defines it (`samp.robot_sdf.robot_points.SelfDistances`): the
  rigid minimum, lowered by the one-joint tables (linear in the joint angle);
* the scene's feature volume sampled at the points, trilinear with the border value outside, as
  `torch.nn.functional.grid_sample(align_corners=True, padding_mode="border")` over the feature cells' box;
* the normalised configurations and `goal_features`.

The learned layers stay torch's (`SAMPNet.head`), so a checkpoint means the same network on either path.
Arithmetic is float64 where torch's is float32 (kinematics, coordinates, interpolation weights), so the
inputs agree with the torch path's to float32 rounding, not to the bit; `tests/policy/test_compiled_step.py`
holds the two together, and `SAMPStepPolicy(compiled=False)` (`load_policy(..., compiled=False)`) keeps the
torch path.
"""

from __future__ import annotations

import math

import numba
import numpy as np
import torch

from samp.sim.broadphase import serial_link_poses

__all__ = ["StepInputs", "compiled_step_available"]


def compiled_step_available(system) -> bool:
    """Whether `StepInputs` can serve this system's rollout steps: on the CPU, with a serial arm and the robot
    SDF at the near pairs (the rigid part and the tables), which is what it computes."""
    return (system.device.type == "cpu" and system.robot.serial_fk is not None
            and system.robot_sdf_pairs == "near" and system.robot_sdf_tables >= 2)


class StepInputs:
    """The constants of one policy (robot, robot SDF tables, normalisation) as numpy arrays, and the call that
    turns q and q_goal into the network's inputs.

    Args:
        system: a fitted `PolicySystem` for which `compiled_step_available` holds.
    """

    def __init__(self, system):
        if not compiled_step_available(system):
            raise ValueError("the compiled step needs a CPU policy of a serial arm with robot_sdf_pairs=near; this one "
                             f"is on {system.device} with robot_sdf_pairs={system.robot_sdf_pairs}")
        robot, cfg = system.robot, system.net_cfg
        distances = system.robot_sdf.self_distances(system.robot_sdf_tables)
        self.fk = robot.serial_fk.numpy_constants()
        self.points = robot.points.detach().cpu().double().numpy()  # (M, 3) in their links' frames
        self.point_link = robot.point_collision_links.cpu().numpy()  # (M,) into the link poses
        self.limits = robot.joint_limits.detach().cpu().double().numpy()  # (n, 2)
        self.base = distances.base.cpu().float().numpy()  # (M,) the rigid pairs' minimum
        if distances.table is None or not len(distances.table_point):
            self.table, self.table_point = np.zeros((0, 2), np.float32), np.zeros(0, np.int64)
            self.table_joint, self.table_lo, self.table_span = np.zeros(0, np.int64), np.zeros(0), np.ones(0)
        else:
            self.table = distances.table.cpu().float().numpy()  # (P, K) network values at K angles
            self.table_point = distances.table_point.cpu().numpy()
            self.table_joint = distances.table_joint.cpu().numpy()
            self.table_lo = distances.table_lo.cpu().double().numpy()
            self.table_span = distances.table_span.cpu().double().numpy()
        self.robot_sdf_feature = bool(system.hparams.robot_sdf_feature)
        self.goal_extra = bool(cfg.goal_features)
        self.env_encoder = bool(cfg.env_encoder)
        self.system = system
        self.box = (np.zeros(3), np.ones(3))
        # Load the kernel now (compiled once per machine, then read from numba's cache in ~0.2 s), outside any
        # timed step, on a blank feature volume; a step before `set_features` is refused (IndexError).
        self.features = np.zeros((1, 2, 2, 2, cfg.channels), np.float32)
        home = robot.home.detach().cpu().double()[None]
        self(home, home, torch.zeros(1, dtype=torch.long))
        self.features = np.zeros((0, 2, 2, 2, cfg.channels), np.float32)

    def set_features(self, features: torch.Tensor | None) -> None:
        """The batch's encoded scenes (S, C, n', n', n') from `PolicySystem.encode` (None without the env branch)."""
        if features is None:
            return
        system = self.system
        # (S, n', n', n', C): a cell's channels side by side, read together by each corner of the interpolation
        self.features = np.ascontiguousarray(features.detach().cpu().float().permute(0, 2, 3, 4, 1).numpy())
        lo, hi = system.net.env.feature_bounds(system.bounds, system.n_e, features.shape[-1])
        self.box = (np.asarray(lo, np.float64), np.asarray(hi, np.float64))

    def __call__(self, q: torch.Tensor, q_goal: torch.Tensor, scene_index: torch.Tensor):
        """q, q_goal (B, n) radians, scene_index (B,) into the features (IndexError outside them) -> the torch
        tensors SAMPNet.head reads: u_t (B, n), the config MLP's input (B, 4n + 1 or 2n), the env MLP's
        (B, M (C + 1)) and the PointNet's (B, M, 4), float32."""
        n = len(self.limits)
        if q.dim() != 2 or q.shape[1] != n or q_goal.shape != q.shape:
            raise ValueError(f"q and q_goal must have shape (B, {n}), got {tuple(q.shape)} and {tuple(q_goal.shape)}")
        A, D, axes, K, K2, revolute, take = self.fk
        lo, hi = self.box
        u_t, config_in, env_in, point_in = _step_inputs(
            q.detach().cpu().double().numpy(), q_goal.detach().cpu().double().numpy(), self.limits,
            A, D, axes, K, K2, revolute, take, self.points, self.point_link, self.base, self.table, self.table_point,
            self.table_joint, self.table_lo, self.table_span, self.features, scene_index.cpu().numpy(), lo, hi,
            self.env_encoder, self.robot_sdf_feature, self.goal_extra)
        return tuple(torch.from_numpy(x) for x in (u_t, config_in, env_in, point_in))


@numba.njit(cache=True, nogil=True)
def _step_inputs(q, q_goal, limits, A, D, axes, K, K2, revolute, take, points, point_link, base, table, table_point,
                 table_joint, table_lo, table_span, features, scene_index, lo, hi, env_encoder, robot_sdf_feature,
                 goal_extra):
    B, n = q.shape
    M = points.shape[0]
    C = features.shape[4]
    P, T = table.shape
    u_t = np.empty((B, n), np.float32)
    config_in = np.empty((B, 4 * n + 1 if goal_extra else 2 * n), np.float32)
    env_in = np.empty((B, M * (C + 1) if env_encoder else 0), np.float32)
    point_in = np.empty((B, M, 4), np.float32)
    d = np.empty(M)
    xyz = np.empty((M, 3))
    u = np.empty((2, n))
    poses = serial_link_poses(q, A, D, axes, K, K2, revolute, take)  # (B, L, 4, 4)
    for b in range(B):
        if env_encoder and not 0 <= scene_index[b] < features.shape[0]:
            raise IndexError("scene_index is outside the encoded scenes (reset the policy with this batch's grids)")
        finite = True
        for j in range(n):
            finite = finite and math.isfinite(q[b, j])
        if not finite:  # an undefined robot: every input NaN, as on the torch path
            u_t[b] = np.nan
            config_in[b] = np.nan
            env_in[b] = np.nan
            point_in[b] = np.nan
            continue
        # Normalised configurations and the goal terms (samp.policy.network.normalize, goal_features).
        dist = 0.0
        for j in range(n):
            span = limits[j, 1] - limits[j, 0]
            u[0, j] = 2.0 * (q[b, j] - limits[j, 0]) / span - 1.0
            u[1, j] = 2.0 * (q_goal[b, j] - limits[j, 0]) / span - 1.0
            dist += (u[1, j] - u[0, j]) ** 2
        dist = math.sqrt(dist)
        for j in range(n):
            u_t[b, j] = config_in[b, j] = u[0, j]
            config_in[b, n + j] = u[1, j]
            if goal_extra:
                config_in[b, 2 * n + j] = u[1, j] - u[0, j]
                config_in[b, 3 * n + j] = (u[1, j] - u[0, j]) / max(dist, 1e-3)
        if goal_extra:
            config_in[b, 4 * n] = dist
        # The robot points posed at q, and the robot SDF there: the rigid minimum lowered by the tables.
        for m in range(M):
            T_l = poses[b, point_link[m]]
            for r in range(3):
                xyz[m, r] = T_l[r, 0] * points[m, 0] + T_l[r, 1] * points[m, 1] + T_l[r, 2] * points[m, 2] + T_l[r, 3]
            d[m] = base[m]
        for p in range(P):
            t = min(max((q[b, table_joint[p]] - table_lo[p]) / table_span[p], 0.0), 1.0) * (T - 1)
            i = min(int(math.floor(t)), T - 2)
            f = t - i
            v = table[p, i] * (1.0 - f) + table[p, i + 1] * f
            if v < d[table_point[p]]:
                d[table_point[p]] = v
        for m in range(M):
            value = d[m] if robot_sdf_feature else 0.0
            for r in range(3):
                point_in[b, m, r] = xyz[m, r]
            point_in[b, m, 3] = value
            if env_encoder:
                _trilinear(features, scene_index[b], xyz[m, 0], xyz[m, 1], xyz[m, 2], lo, hi, env_in[b], m * (C + 1))
                env_in[b, m * (C + 1) + C] = value
    return u_t, config_in, env_in, point_in


@numba.njit(cache=True, nogil=True, inline="always")
def _cell(x, lo, hi, size):
    """A coordinate -> (the cell's first index, the fraction across it) in a grid of `size` cell centres from lo to
    hi, clamped to the border."""
    t = min(max((x - lo) / (hi - lo) * (size - 1), 0.0), size - 1.0)
    i = min(int(math.floor(t)), size - 2)
    return i, t - i


@numba.njit(cache=True, nogil=True, inline="always")
def _trilinear(features, s, x, y, z, lo, hi, out, at):
    """out[at:at + C] <- the volume features[s] (S, size, size, size, C), indexed (x, y, z) with its cell centres
    spanning the box lo..hi, at the point (x, y, z): trilinear, clamped to the border (grid_sample's
    align_corners=True with border padding)."""
    size, C = features.shape[1], features.shape[4]
    x0, fx = _cell(x, lo[0], hi[0], size)
    y0, fy = _cell(y, lo[1], hi[1], size)
    z0, fz = _cell(z, lo[2], hi[2], size)
    v = features[s]
    for c in range(C):
        front = ((v[x0, y0, z0, c] * (1 - fz) + v[x0, y0, z0 + 1, c] * fz) * (1 - fy)
                 + (v[x0, y0 + 1, z0, c] * (1 - fz) + v[x0, y0 + 1, z0 + 1, c] * fz) * fy)
        back = ((v[x0 + 1, y0, z0, c] * (1 - fz) + v[x0 + 1, y0, z0 + 1, c] * fz) * (1 - fy)
                + (v[x0 + 1, y0 + 1, z0, c] * (1 - fz) + v[x0 + 1, y0 + 1, z0 + 1, c] * fz) * fy)
        out[at + c] = front * (1 - fx) + back * fx
