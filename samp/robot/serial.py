"""Forward kinematics of a serial arm's links in a few batched products (what a policy step needs).

Along the path from the base to a link, every transform that does not depend on q (fixed joints,
joint origins, held joints such as a gripper's fingers) is multiplied out once. What remains is

    T_link(q) = A_1 R_1(q_1) A_2 R_2(q_2) ... A_k R_k(q_k) D_link,

with R_j the rotation (or translation) of arm joint j about its axis, A_j the constant transform
before it and D_link the constant transform from the last arm joint before the link to the link. The
k products are shared by all links, so the Panda's 11 links cost 7 chained products and one batched
one, about a third of the work of a general tree traversal. An arm whose links see the arm joints in
another order than a prefix of q (a tree with arm joints on two branches) is refused, and the robot
then uses its general FK.
"""

from __future__ import annotations

import functools

import numpy as np
import torch

__all__ = ["SerialFK"]


def _motion(joint, value: float) -> np.ndarray:
    """(4, 4) transform of `joint` moved by `value` about (revolute) or along (prismatic) its axis."""
    T = np.eye(4)
    if joint.type == "fixed":
        return T
    axis = joint.axis / np.linalg.norm(joint.axis)
    if joint.type in ("revolute", "continuous"):
        K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
        T[:3, :3] = np.eye(3) + np.sin(value) * K + (1 - np.cos(value)) * K @ K
    elif joint.type == "prismatic":
        T[:3, 3] = axis * value
    else:
        raise ValueError(f"joint {joint.name!r} has type {joint.type!r}, which FK does not handle")
    return T


def _joint_motions(q: np.ndarray, *rest) -> np.ndarray:
    """`_joint_motions_py` compiled (numba, cached on disk) on first use: importing the robot costs no numba."""
    return _compiled_joint_motions()(q, *rest)


@functools.cache
def _compiled_joint_motions():
    import numba

    return numba.njit(cache=True, nogil=True)(_joint_motions_py)


def _joint_motions_py(q: np.ndarray, c: np.ndarray, s: np.ndarray, K: np.ndarray, K2: np.ndarray,
                      revolute: np.ndarray, axes: np.ndarray) -> np.ndarray:
    """(B, n, 4, 4) each arm joint's motion: Rodrigues' I + sin K + (1 - cos) K^2 for a revolute joint (c, s:
    (B, n) numpy's cos and sin of q), I with the translation axis * q for a prismatic one. The numbers that
    numpy's elementwise expression gave, to the bit (the same operations in the same order, no fused
    multiply-adds), in one pass instead of a dozen array operations."""
    B, n = q.shape
    J = np.zeros((B, n, 4, 4))
    for b in range(B):
        for j in range(n):
            J[b, j, 3, 3] = 1.0
            if revolute[j]:
                for r in range(3):
                    for col in range(3):
                        eye = 1.0 if r == col else 0.0
                        J[b, j, r, col] = (eye + s[b, j] * K[j, r, col]) + (1.0 - c[b, j]) * K2[j, r, col]
            else:
                for r in range(3):
                    J[b, j, r, r] = 1.0
                    J[b, j, r, 3] = axes[j, r] * q[b, j]
    return J


class SerialFK:
    """Link poses in the base frame for the links `links` of `urdf`, arm joints `joints` (the columns
    of q), other movable joints held at `held` (name -> value, default 0).

    Raises ValueError if the arm is not serial for these links (see the module docstring).
    """

    def __init__(self, urdf, joints: list[str], links: list[str], held: dict[str, float], base_inv: np.ndarray):
        self.joint_names = list(joints)
        revolute = []
        A: list[np.ndarray | None] = [None] * len(joints)  # constant before each arm joint
        D, last = [], []  # per link: constant after its last arm joint, and that joint's index (-1: none)
        for link in links:
            path = []
            while (joint := urdf.parent_joint(link)) is not None:
                path.append(joint)
                link = joint.parent
            T, k = base_inv.copy(), -1  # base-frame poses: the base's inverse pose comes first
            for joint in reversed(path):
                T = T @ joint.origin
                if joint.name in self.joint_names:
                    j = self.joint_names.index(joint.name)
                    if j != k + 1:
                        raise ValueError(f"arm joint {joint.name!r} is not next along the chain to {link!r}")
                    if A[j] is not None and not np.allclose(A[j], T, atol=1e-12):
                        raise ValueError(f"arm joint {joint.name!r} is reached by two different paths")
                    A[j], k, T = T, j, np.eye(4)
                else:
                    T = T @ _motion(joint, held.get(joint.name, 0.0))
            D.append(T)
            last.append(k)
        for j, name in enumerate(self.joint_names):
            if A[j] is None:
                raise ValueError(f"arm joint {name!r} moves none of the links {links}")
            joint = urdf.joints[name]
            if joint.type not in ("revolute", "continuous", "prismatic"):
                raise ValueError(f"arm joint {name!r} has type {joint.type!r}")
            revolute.append(joint.type != "prismatic")
        self._A = torch.from_numpy(np.stack(A))  # (n, 4, 4)
        self._D = torch.from_numpy(np.stack(D))  # (L, 4, 4)
        self._axes = torch.from_numpy(np.stack([urdf.joints[n].axis / np.linalg.norm(urdf.joints[n].axis)
                                                for n in self.joint_names]))  # (n, 3)
        self._revolute = torch.tensor(revolute)
        self._last = torch.tensor(last)
        self._masters = (self._A, self._D, self._axes)
        self.to(torch.float64, torch.device("cpu"))

    def to(self, dtype: torch.dtype, device) -> "SerialFK":
        """Constants in `dtype` on `device`, from the float64 masters (no precision lost in round trips)."""
        A, D, axes = self._masters
        self.A, self.D, self.axes = (x.to(dtype=dtype, device=device) for x in (A, D, axes))
        self.revolute, self.last = self._revolute.to(device), self._last.to(device)
        self.all_revolute = bool(self._revolute.all())
        # a link before the first arm joint reads the identity "product so far"
        self.eye = torch.eye(4, dtype=dtype, device=device)
        return self

    def numpy_constants(self) -> tuple[np.ndarray, ...]:
        """The float64 constants of `numpy` (and of `samp.sim.broadphase.serial_link_poses`): A (n, 4, 4),
        D (L, 4, 4), unit axes (n, 3), their cross-product matrices K and K @ K (n, 3, 3), which joints are
        revolute (n,) and, per link, the index into the running product (n + 1 of them) that it takes (L,)."""
        if not hasattr(self, "_np"):
            A, D, axes = (x.numpy() for x in self._masters)
            K = np.zeros((len(axes), 3, 3))
            K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = (
                -axes[:, 2], axes[:, 1], axes[:, 2], -axes[:, 0], -axes[:, 1], axes[:, 0])
            self._np = (A, D, axes, K, K @ K, self._revolute.numpy(), self._last.numpy() + 1)
        return self._np

    def numpy(self, q: np.ndarray) -> np.ndarray:
        """q (B, n) float64 -> (B, L, 4, 4) float64 link poses, in numpy from the float64 masters: for the
        few configurations of a collision query, where torch's per-call overhead dominates (~10x faster at
        B <= 32). Agrees with `__call__` in float64 to rounding (~1e-15)."""
        A, D, axes, K, K2, revolute, take = self.numpy_constants()
        q = np.ascontiguousarray(q, dtype=np.float64)
        B, n = q.shape
        J = _joint_motions(q, np.cos(q), np.sin(q), K, K2, revolute, axes)  # (B, n, 4, 4)
        local = A @ J  # (B, n, 4, 4)
        prefix = np.empty((B, n + 1, 4, 4))
        prefix[:, 0] = np.eye(4)
        prefix[:, 1] = local[:, 0]
        for j in range(1, n):
            prefix[:, j + 1] = prefix[:, j] @ local[:, j]
        return prefix[:, take] @ D

    def __call__(self, q: torch.Tensor) -> torch.Tensor:
        """q (B, n) -> (B, L, 4, 4) link poses in the base frame."""
        B, n = q.shape
        c, s = q.cos()[..., None, None], q.sin()[..., None, None]  # (B, n, 1, 1)
        K = torch.zeros(n, 3, 3, dtype=q.dtype, device=q.device)  # cross-product matrices of the axes
        x, y, z = self.axes.unbind(-1)
        K[:, 0, 1], K[:, 0, 2], K[:, 1, 0], K[:, 1, 2], K[:, 2, 0], K[:, 2, 1] = -z, y, z, -x, -y, x
        R = torch.eye(3, dtype=q.dtype, device=q.device) + s * K + (1 - c) * (K @ K)  # Rodrigues, (B, n, 3, 3)
        J = torch.zeros(B, n, 4, 4, dtype=q.dtype, device=q.device)
        J[..., 3, 3] = 1
        if self.all_revolute:
            J[..., :3, :3] = R
        else:
            rev = self.revolute[:, None, None]
            J[..., :3, :3] = torch.where(rev, R, torch.eye(3, dtype=q.dtype, device=q.device))
            J[..., :3, 3] = torch.where(self.revolute[:, None], 0.0, self.axes * q[..., None])
        local = self.A @ J  # (B, n, 4, 4)
        chain = [local[:, 0]]
        for j in range(1, n):
            chain.append(chain[-1] @ local[:, j])
        prefix = torch.stack([self.eye.expand(B, 4, 4), *chain], dim=1)  # (B, n + 1, 4, 4): index k + 1
        return prefix[:, self.last + 1] @ self.D
