"""Batched damped-least-squares inverse kinematics on `Robot.fk`, in torch.

Every target pose gets `seeds` random initial configurations, all solved in parallel for a fixed number
of iterations (a seed stops once its error is below `SETTLED`, where its steps no longer move it): dq = J^T (J J^T + lambda^2 I)^-1 e (Wampler 1986; Buss, "Introduction to inverse
kinematics with Jacobian transpose, pseudoinverse and damped least squares methods", 2004), with the
step capped at `max_step` per joint and q clamped to the joint limits after each step; joints at a
limit that the step would push beyond it are locked for that step. J is the
geometric Jacobian built from the joint axes and origins that FK gives (one FK per iteration, no
autograd). The orientation error is 1/2 sum_i r_i x r*_i over the columns of the current and target
rotations (Siciliano et al., "Robotics", eq. 3.85): the rotation vector for small errors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from samp.expert.config import IKConfig

SETTLED = 1e-12  # a seed whose pose error (6D norm) is below this stops: its later steps would move it less
RESTART_ERROR = 0.02  # a seed whose pose error (metres + radians, 6D norm) is above this at a restart is redrawn

__all__ = ["IKResult", "geometric_jacobian", "limits_inward", "pose_errors", "rotation_angle", "solve_ik"]


@dataclass
class IKResult:
    """Solutions for K target poses with S seeds each."""

    q: torch.Tensor  # (K, S, n) radians, within the exact joint limits (also after conversion to float64)
    position_error: torch.Tensor  # (K, S) metres
    rotation_error: torch.Tensor  # (K, S) radians
    converged: torch.Tensor  # (K, S) bool, within the configured tolerances


def rotation_angle(Ra: torch.Tensor, Rb: torch.Tensor) -> torch.Tensor:
    """(..., 3, 3) rotations -> (...) angle of Ra^T Rb in radians, in [0, pi]."""
    trace = torch.einsum("...ij,...ij->...", Ra, Rb)  # trace(Ra^T Rb)
    return torch.acos(((trace - 1) / 2).clamp(-1.0, 1.0))


def pose_errors(T: torch.Tensor, target: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """T, target (..., 4, 4) -> position error (...) metres and rotation error (...) radians."""
    return (T[..., :3, 3] - target[..., :3, 3]).norm(dim=-1), rotation_angle(T[..., :3, :3], target[..., :3, :3])


def _joint_axes(robot) -> tuple[list[str], torch.Tensor, torch.Tensor]:
    """The arm joints' child links, their axes in the child frame (n, 3) and a revolute mask (n,)."""
    children, axes, revolute = [], [], []
    for name in robot.joint_names:
        joint = robot.urdf.joints[name]
        if joint.type not in ("revolute", "continuous", "prismatic"):
            raise ValueError(f"IK supports revolute and prismatic joints; {robot.name}'s {name!r} is {joint.type!r}")
        children.append(joint.child)
        axes.append(torch.as_tensor(joint.axis / (joint.axis ** 2).sum() ** 0.5))
        revolute.append(joint.type != "prismatic")
    return children, torch.stack(axes).to(robot.dtype), torch.tensor(revolute)


def geometric_jacobian(robot, q: torch.Tensor, joints=None) -> tuple[torch.Tensor, torch.Tensor]:
    """q (B, n) -> end-effector pose (B, 4, 4) and geometric Jacobian (B, 6, n) in the base frame,
    rows (linear velocity, angular velocity)."""
    children, axes, revolute = joints or _joint_axes(robot)
    serial = robot.frames_fk((*children, robot.ee_link))  # a serial arm: the frames in a few products
    if serial is not None and q.device.type == "cpu":
        robot._check_q(q)  # numpy's batched 4x4 products are several times faster than torch's on a CPU
        return _jacobian_numpy(serial, q, axes, revolute)
    if serial is not None:
        robot._check_q(q)
        frames = serial(q)  # (B, n + 1, 4, 4)
        T_ee, T_j = frames[:, -1], frames[:, :-1]
    else:
        frames = robot.fk(q)
        T_ee = frames[robot.ee_link]
        T_j = torch.stack([frames[c] for c in children], dim=1)  # (B, n, 4, 4) joint frames (= child link frames)
    axis = torch.einsum("bnij,nj->bni", T_j[..., :3, :3], axes.to(q))  # (B, n, 3) in the base frame
    lever = T_ee[:, None, :3, 3] - T_j[..., :3, 3]  # (B, n, 3)
    rev = revolute.to(q.device)[None, :, None]
    linear = torch.where(rev, torch.cross(axis, lever, dim=-1), axis)
    angular = torch.where(rev, axis, torch.zeros_like(axis))
    return T_ee, torch.cat([linear, angular], dim=-1).transpose(1, 2)  # (B, 6, n)


def _jacobian_numpy(serial, q: torch.Tensor, axes: torch.Tensor, revolute: torch.Tensor):
    """`geometric_jacobian` of a serial arm on the CPU, in float64 numpy, returned in q's dtype."""
    frames = serial.numpy(q.detach().double().numpy())  # (B, n + 1, 4, 4)
    T_ee, T_j = frames[:, -1], frames[:, :-1]
    axis = (T_j[..., :3, :3] @ axes.double().numpy()[:, :, None])[..., 0]  # (B, n, 3) in the base frame
    lever = T_ee[:, None, :3, 3] - T_j[..., :3, 3]  # (B, n, 3)
    rev = revolute.numpy()[None, :, None]
    linear = np.where(rev, np.cross(axis, lever), axis)
    angular = np.where(rev, axis, 0.0)
    J = np.concatenate([linear, angular], axis=-1).transpose(0, 2, 1)  # (B, 6, n)
    return torch.from_numpy(T_ee).to(q.dtype), torch.from_numpy(np.ascontiguousarray(J)).to(q.dtype)


def _error(T: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """(B, 4, 4) current and target poses -> (B, 6) twist-like error (position, orientation)."""
    rot = 0.5 * torch.cross(T[:, :3, :3], target[:, :3, :3], dim=1).sum(dim=-1)  # sum over columns
    return torch.cat([target[:, :3, 3] - T[:, :3, 3], rot], dim=-1)


def _dls_step(J: torch.Tensor, e: torch.Tensor, damped_eye: torch.Tensor) -> torch.Tensor:
    """J (B, 6, n), e (B, 6) -> dq (B, n) = J^T (J J^T + lambda^2 I)^-1 e."""
    return (J.transpose(1, 2) @ torch.linalg.solve(J @ J.transpose(1, 2) + damped_eye, e[..., None]))[..., 0]


def limits_inward(robot) -> tuple[torch.Tensor, torch.Tensor]:
    """(n,) lower and (n,) upper joint limits in the robot's dtype, rounded inward.

    Rounded to the nearest float32, a limit can move outward by up to ~1e-7 rad; a configuration clamped
    onto it would then lie beyond the exact (float64) limit, which the World forgives (LIMIT_TOLERANCE)
    but OMPL's bounds check refuses ("invalid bounds"). Rounded inward, every clamped configuration,
    converted to float64, is within the limits the planner uses."""
    exact = robot.joint_limits.to(dtype=torch.float64, device=robot.device)  # (n, 2), from the config
    lo, hi = exact.to(robot.dtype).unbind(-1)
    lo = torch.where(lo.double() < exact[:, 0], torch.nextafter(lo, torch.full_like(lo, float("inf"))), lo)
    hi = torch.where(hi.double() > exact[:, 1], torch.nextafter(hi, torch.full_like(hi, float("-inf"))), hi)
    return lo, hi


def _random_q(robot, shape: tuple[int, ...], generator: torch.Generator) -> torch.Tensor:
    """(*shape, n) configurations uniform within the joint limits."""
    lo, hi = limits_inward(robot)
    u = torch.rand(*shape, robot.dof, generator=generator, dtype=robot.dtype)
    return torch.minimum(torch.maximum(lo + u * (hi - lo), lo), hi)  # lo + u (hi - lo) can round past hi


def solve_ik(robot, targets: torch.Tensor, cfg: IKConfig | None = None, *, generator: torch.Generator,
             q_init: torch.Tensor | None = None) -> IKResult:
    """Solve targets (K, 4, 4) end-effector poses in the base frame from `cfg.seeds` random seeds each.

    q_init (K, m, n) or (m, n), optional: configurations used as the first m seeds (e.g. the current
    configuration). Seeds are drawn with `generator` (CPU), so a seeded generator gives identical results.
    """
    cfg = cfg or IKConfig()
    if not isinstance(targets, torch.Tensor) or targets.ndim != 3 or targets.shape[1:] != (4, 4):
        raise ValueError(f"targets must be a (K, 4, 4) tensor of poses, got "
                         f"{tuple(targets.shape) if isinstance(targets, torch.Tensor) else type(targets).__name__}")
    K, S, n = len(targets), cfg.seeds, robot.dof
    targets = targets.to(robot.dtype)
    q = _random_q(robot, (K, S), generator)  # (K, S, n)
    if q_init is not None:
        q_init = torch.as_tensor(q_init, dtype=robot.dtype).expand(K, -1, n) if q_init.ndim == 2 else q_init
        m = min(q_init.shape[1], S)
        q[:, :m] = q_init[:, :m].to(robot.dtype)
    lo, hi = limits_inward(robot)
    q = q.reshape(K * S, n).clamp(lo, hi)
    flat_targets = targets[:, None].expand(K, S, 4, 4).reshape(K * S, 4, 4)
    joints = _joint_axes(robot)
    eye = torch.eye(6, dtype=robot.dtype) * cfg.damping ** 2
    with torch.no_grad():
        restart_at = {cfg.iterations * (r + 1) // (cfg.restarts + 1) for r in range(cfg.restarts)}
        active = torch.arange(K * S)  # seeds still moving: a settled seed's further steps are below SETTLED
        for it in range(cfg.iterations):
            fresh = _random_q(robot, (K * S,), generator)[active] if it in restart_at else None  # every draw taken
            if len(active) == 0:
                continue
            qa, goal = q[active], flat_targets[active]
            T, J = geometric_jacobian(robot, qa, joints)  # (B, 4, 4), (B, 6, n)
            e = _error(T, goal)  # (B, 6)
            if fresh is not None:  # seeds still far off are stuck in a local minimum: draw them afresh
                stuck = e.norm(dim=1) > RESTART_ERROR
                qa = torch.where(stuck[:, None], fresh, qa)
                T, J = geometric_jacobian(robot, qa, joints)
                e = _error(T, goal)
            settled = e.norm(dim=1) < SETTLED
            dq = _dls_step(J, e, eye)  # (B, n)
            # Joints at a limit and pushed beyond it are locked for this step (an active set), so the
            # other joints take up the error instead of the clamp undoing part of every step.
            locked = ((qa <= lo) & (dq < 0)) | ((qa >= hi) & (dq > 0))  # (B, n)
            rows = torch.nonzero(locked.any(dim=1))[:, 0]
            if len(rows):  # solved again without the locked joints: only the rows that have one (each row's
                # solve is its own, whatever the batch, so the other rows' steps are those just computed)
                dq[rows] = _dls_step(J[rows] * ~locked[rows, None, :], e[rows], eye)
            scale = (cfg.max_step / dq.abs().amax(dim=1, keepdim=True).clamp_min(1e-12)).clamp(max=1.0)
            q[active] = torch.where(settled[:, None], qa, (qa + dq * scale).clamp(lo, hi))
            active = active[~settled]
        pos_err, rot_err = pose_errors(geometric_jacobian(robot, q, joints)[0], flat_targets)
    converged = (pos_err <= cfg.position_tolerance) & (rot_err <= cfg.rotation_tolerance)
    return IKResult(q.reshape(K, S, n), pos_err.reshape(K, S), rot_err.reshape(K, S), converged.reshape(K, S))
