"""The broadphase of `samp.sim.World`'s queries compiled with numba: forward kinematics of a serial arm, the
collision parts' world boxes, their gaps to the obstacles' boxes, and the self pairs that may touch, in one
call per query.

The expert asks `World.in_collision` about a few configurations at a time (a motion's first chunk of 8
states, one sampled state) about 250 times per problem. In numpy the broadphase is about 15 array
operations, ~0.6 ms a call whatever the batch, and it was two thirds of generation's time; the same
arithmetic in one compiled loop takes tens of microseconds. `World` keeps its numpy broadphase as the
reference (and for arms whose FK is not serial); the tests compare the two.

Same inputs, same arithmetic as the numpy path, but not the same rounding: numpy multiplies the 4 x 4 and
3 x V matrices through BLAS, whose kernels (and their fused multiply-adds) depend on the CPU. Poses a
rounding error apart move pybullet's distances by up to ~1e-7 m (its GJK's sensitivity), so an answer could
differ only for a distance that close to the margin: the pinned dataset bytes
(`tests/data/test_data_generation.py`) and a whole `standard` dataset (every file equal but for one problem
that timed out) showed none.

Compiled functions are cached on disk beside this file (numba's `cache=True`; elsewhere when that folder is
read-only), so a process pays the ~8 s compilation only once per machine and numba version.
"""

from __future__ import annotations

import math

import numba
import numpy as np

__all__ = ["part_gaps", "quaternions", "serial_link_poses"]


@numba.njit(cache=True, nogil=True)
def _matmul4(a: np.ndarray, b: np.ndarray, out: np.ndarray) -> None:
    for r in range(4):
        for c in range(4):
            out[r, c] = a[r, 0] * b[0, c] + a[r, 1] * b[1, c] + a[r, 2] * b[2, c] + a[r, 3] * b[3, c]


@numba.njit(cache=True, nogil=True)
def serial_link_poses(q: np.ndarray, A: np.ndarray, D: np.ndarray, axes: np.ndarray, K: np.ndarray, K2: np.ndarray,
                      revolute: np.ndarray, take: np.ndarray) -> np.ndarray:
    """q (B, n) -> (B, L, 4, 4) link poses of a serial arm, `samp.robot.serial.SerialFK.numpy`'s products:
    T_l = A_1 J_1(q_1) ... A_k J_k(q_k) D_l with k = take[l] (0: before the first arm joint), J a joint's
    Rodrigues rotation I + sin K + (1 - cos) K^2 (revolute) or translation along its axis (prismatic)."""
    B, n = q.shape
    L = D.shape[0]
    out = np.empty((B, L, 4, 4))
    prefix = np.empty((n + 1, 4, 4))
    J, local = np.zeros((4, 4)), np.empty((4, 4))
    for b in range(B):
        prefix[0] = np.eye(4)
        for j in range(n):
            J[:] = 0.0
            J[3, 3] = 1.0
            if revolute[j]:
                s, c = math.sin(q[b, j]), math.cos(q[b, j])
                for r in range(3):
                    for col in range(3):
                        J[r, col] = (1.0 if r == col else 0.0) + s * K[j, r, col] + (1.0 - c) * K2[j, r, col]
            else:
                for r in range(3):
                    J[r, r] = 1.0
                    J[r, 3] = axes[j, r] * q[b, j]
            _matmul4(A[j], J, local)
            _matmul4(prefix[j], local, prefix[j + 1])
        for li in range(L):
            _matmul4(prefix[take[li]], D[li], out[b, li])
    return out


@numba.njit(cache=True, nogil=True)
def _box_of(R: np.ndarray, t: np.ndarray, vertices: np.ndarray, count: int, lo: np.ndarray, hi: np.ndarray) -> None:
    """lo, hi (3,) <- the axis-aligned box of R @ vertices[:, :count] + t, vertices (3, V)."""
    for r in range(3):
        low, high = np.inf, -np.inf
        for v in range(count):
            x = R[r, 0] * vertices[0, v] + R[r, 1] * vertices[1, v] + R[r, 2] * vertices[2, v]
            low, high = min(low, x), max(high, x)
        lo[r], hi[r] = low + t[r], high + t[r]


@numba.njit(cache=True, nogil=True)
def _gap(lo_a: np.ndarray, hi_a: np.ndarray, lo_b: np.ndarray, hi_b: np.ndarray) -> float:
    """Euclidean distance between two axis-aligned boxes (3,) corners; 0 if they overlap."""
    total = 0.0
    for r in range(3):
        d = max(max(lo_a[r] - hi_b[r], lo_b[r] - hi_a[r]), 0.0)
        total += d * d
    return math.sqrt(total)


@numba.njit(cache=True, nogil=True)
def _frame_gap(Ta: np.ndarray, Tb: np.ndarray, vertices: np.ndarray, count: int, local_lo: np.ndarray,
               local_hi: np.ndarray) -> float:
    """Box gap between a part (vertices (3, V), `count` of them real) posed at Ta (4, 4) and another part's
    box (local_lo, local_hi) in its own link frame, posed at Tb: the former's box taken in that frame."""
    M, shift = np.empty((3, 3)), np.empty(3)
    d0, d1, d2 = Ta[0, 3] - Tb[0, 3], Ta[1, 3] - Tb[1, 3], Ta[2, 3] - Tb[2, 3]  # t_a - t_b
    for r in range(3):
        for c in range(3):
            M[r, c] = Tb[0, r] * Ta[0, c] + Tb[1, r] * Ta[1, c] + Tb[2, r] * Ta[2, c]  # R_b^T R_a
        shift[r] = Tb[0, r] * d0 + Tb[1, r] * d1 + Tb[2, r] * d2  # R_b^T (t_a - t_b)
    lo, hi = np.empty(3), np.empty(3)
    _box_of(M, shift, vertices, count, lo, hi)
    return _gap(lo, hi, local_lo, local_hi)


@numba.njit(cache=True, nogil=True)
def part_gaps(T: np.ndarray, part_links: np.ndarray, vertices: np.ndarray, counts: np.ndarray, moving: np.ndarray,
              obstacle_lo: np.ndarray, obstacle_hi: np.ndarray, pairs: np.ndarray, local_lo: np.ndarray,
              local_hi: np.ndarray, self_collision: bool, slack: float) -> tuple[np.ndarray, np.ndarray]:
    """T (B, L, 4, 4) link poses -> the box gaps (B, Pm, K) of the moving parts to the obstacles, and the
    self pairs (B, S) that may touch: world boxes overlapping and, in the link frame of either part, boxes
    no more than `slack` apart (`World._apart_in_link_frames`); all False unless `self_collision`.

    part_links (P,): each part's link; vertices (P, 3, V), counts (P,) of them real; moving (Pm,) the parts
    checked against obstacles; obstacle_lo, obstacle_hi (K, 3); pairs (S, 2) allowed part pairs;
    local_lo, local_hi (P, 3) each part's box in its link frame."""
    B, P, Pm, K, S = T.shape[0], part_links.shape[0], moving.shape[0], obstacle_lo.shape[0], pairs.shape[0]
    gaps = np.empty((B, Pm, K))
    touch = np.zeros((B, S), dtype=np.bool_)
    lo, hi = np.empty((P, 3)), np.empty((P, 3))
    for b in range(B):
        for p in range(P):
            pose = T[b, part_links[p]]
            _box_of(pose[:3, :3], pose[:3, 3], vertices[p], counts[p], lo[p], hi[p])
        for i in range(Pm):
            for k in range(K):
                gaps[b, i, k] = _gap(lo[moving[i]], hi[moving[i]], obstacle_lo[k], obstacle_hi[k])
        if not self_collision:
            continue
        for s in range(S):
            a, c = pairs[s, 0], pairs[s, 1]
            if _gap(lo[a], hi[a], lo[c], hi[c]) > 0.0:
                continue
            Ta, Tc = T[b, part_links[a]], T[b, part_links[c]]
            gap = _frame_gap(Ta, Tc, vertices[a], counts[a], local_lo[c], local_hi[c])
            if gap <= slack:
                gap = max(gap, _frame_gap(Tc, Ta, vertices[c], counts[c], local_lo[a], local_hi[a]))
            touch[b, s] = gap <= slack
    return gaps, touch


@numba.njit(cache=True, nogil=True)
def quaternions(T: np.ndarray) -> np.ndarray:
    """(B, L, 4, 4) poses -> (B, L, 4) unit quaternions x, y, z, w of their rotations, by the method of
    `samp.robot.bodies.matrix_to_quaternion` (the largest of the four candidate components first)."""
    B, L = T.shape[0], T.shape[1]
    out = np.empty((B, L, 4))
    for b in range(B):
        for li in range(L):
            m, q = T[b, li], out[b, li]
            trace = m[0, 0] + m[1, 1] + m[2, 2]
            k, largest = 0, m[0, 0]  # the first largest of (m00, m11, m22, trace), as numpy's argmax
            for i in range(1, 3):
                if m[i, i] > largest:
                    k, largest = i, m[i, i]
            if trace > largest:
                k = 3
            if k < 3:
                j, h = (k + 1) % 3, (k + 2) % 3
                q[k] = 1.0 - trace + 2.0 * m[k, k]
                q[j] = m[j, k] + m[k, j]
                q[h] = m[h, k] + m[k, h]
                q[3] = m[h, j] - m[j, h]
            else:
                q[0], q[1], q[2], q[3] = m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1], 1.0 + trace
            norm = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
            for i in range(4):
                q[i] /= norm
    return out
