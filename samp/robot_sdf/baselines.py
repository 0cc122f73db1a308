"""Baselines of the paper's Table III, with the link-network interface of `samp.robot_sdf.model`.

- `NNSDF`: one MLP for all links on a positional encoding of the link-box point (NeRF-style sin/cos at
  octave frequencies) plus a one-hot link code. Trained like the hash grid (`RobotSDFSystem`).
- `BernsteinSDF` (RDF, Li et al. 2024): per link a tensor-product Bernstein polynomial with
  `n_basis` functions per axis (8 or 24 in Table III), fitted by least squares (`fit_bernstein`).

The least-squares problem for N = 24 has 24^3 = 13824 unknowns per link, so forming the normal
equations costs points x 13824^2 flops (minutes per link on a CPU). `fit_bernstein` instead runs
conjugate gradients on the normal equations without forming them: the design matrix is applied as
three small per-axis factors. It works in the orthonormal Legendre basis, which spans the same
polynomials and is far better conditioned than Bernstein's, warm-starts from the solution of lower
degree, and converts the result to Bernstein weights at the end, so the model evaluates exactly the
RDF representation. A tiny ridge term keeps the corners of the box, where few samples fall, bounded.
Bernstein weights of degree 23 reach about 1e6 with alternating signs, so they are kept and evaluated
in float64 whatever the input dtype.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import torch
from torch import nn

from samp.robot_sdf.model import mlp

__all__ = ["BernsteinSDF", "FitInfo", "NNSDF", "bernstein_basis", "fit_bernstein", "legendre_basis"]


class NNSDF(nn.Module):
    """MLP on [u, sin(2^k pi u), cos(2^k pi u) for k < frequencies, one-hot(link)] -> distance."""

    label = "NN-SDF"

    def __init__(self, num_links: int, frequencies: int = 6, hidden: list[int] | tuple = (256, 256, 256),
                 activation: str = "relu"):
        super().__init__()
        if num_links < 1 or frequencies < 0:
            raise ValueError(f"need num_links >= 1 and frequencies >= 0, got {num_links}, {frequencies}")
        self.num_links = num_links
        self.config = {"num_links": num_links, "frequencies": frequencies, "hidden": list(hidden), "activation": activation}
        self.register_buffer("freqs", (2.0 ** torch.arange(frequencies)) * math.pi)
        self.net = mlp(3 + 6 * frequencies + num_links, list(hidden), 1, activation)

    def forward(self, u: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
        """u (P, 3) in [-1, 1]^3, link (P,) -> (P,) distance in normalised units."""
        angles = (u[:, :, None] * self.freqs.to(u.dtype)).flatten(1)  # (P, 3 F)
        code = nn.functional.one_hot(link, self.num_links).to(u.dtype)
        return self.net(torch.cat([u, angles.sin(), angles.cos(), code], dim=1)).squeeze(-1)


def bernstein_basis(t: torch.Tensor, n_basis: int) -> torch.Tensor:
    """(...,) t in [0, 1] -> (..., n_basis): C(n, k) t^k (1 - t)^(n - k), n = n_basis - 1."""
    n = n_basis - 1
    k = torch.arange(n_basis, dtype=t.dtype, device=t.device)
    binom = torch.tensor([math.comb(n, i) for i in range(n_basis)], dtype=t.dtype, device=t.device)
    return binom * t[..., None] ** k * (1 - t[..., None]) ** (n - k)


def legendre_basis(x: torch.Tensor, n_basis: int) -> torch.Tensor:
    """(...,) x in [-1, 1] -> (..., n_basis) Legendre polynomials scaled to unit mean square on [-1, 1]."""
    polys = [torch.ones_like(x), x]
    for k in range(1, n_basis - 1):  # Bonnet's recursion
        polys.append(((2 * k + 1) * x * polys[k] - k * polys[k - 1]) / (k + 1))
    scale = torch.sqrt(2 * torch.arange(n_basis, dtype=x.dtype, device=x.device) + 1)
    return torch.stack(polys[:n_basis], dim=-1) * scale


def _legendre_to_bernstein(n_basis: int) -> torch.Tensor:
    """(n, n) float64 M with legendre_basis(2t - 1)[k] = sum_j M[k, j] bernstein_basis(t)[j], by
    interpolation at Chebyshev nodes (both bases span the polynomials of degree n - 1)."""
    nodes = 0.5 - 0.5 * torch.cos(torch.pi * (torch.arange(n_basis, dtype=torch.float64) + 0.5) / n_basis)
    return torch.linalg.solve(bernstein_basis(nodes, n_basis), legendre_basis(2 * nodes - 1, n_basis)).T


class BernsteinSDF(nn.Module):
    """Per-link tensor-product Bernstein polynomials: weights (L, N, N, N), evaluated in float64."""

    def __init__(self, num_links: int, n_basis: int = 8):
        super().__init__()
        if num_links < 1 or n_basis < 2:
            raise ValueError(f"need num_links >= 1 and n_basis >= 2, got {num_links}, {n_basis}")
        self.num_links, self.n_basis = num_links, n_basis
        self.config = {"num_links": num_links, "n_basis": n_basis}
        self.register_buffer("weights", torch.zeros(num_links, n_basis, n_basis, n_basis, dtype=torch.float64))

    @property
    def label(self) -> str:
        return f"RDF (N={self.n_basis})"

    def _apply(self, fn, recurse=True):
        """Keep the weights float64 through `.to(dtype)` / `.float()` (module docstring)."""
        super()._apply(fn, recurse)
        self.weights = self.weights.to(torch.float64)
        return self

    def forward(self, u: torch.Tensor, link: torch.Tensor) -> torch.Tensor:
        """u (P, 3) in [-1, 1]^3, link (P,) -> (P,) distance in normalised units (u's dtype)."""
        n = self.n_basis
        t = ((u.to(torch.float64).clamp(-1, 1) + 1) / 2)
        basis = bernstein_basis(t, n)  # (P, 3, N)
        out = torch.zeros(len(u), dtype=torch.float64, device=u.device)
        for i in torch.unique(link).tolist():
            rows = torch.nonzero(link == i).flatten()
            b = basis[rows]
            out = out.index_put((rows,), _contract(self.weights[i], b[:, 0], b[:, 1], b[:, 2]))
        return out.to(u.dtype)


def _contract(w: torch.Tensor, bx: torch.Tensor, by: torch.Tensor, bz: torch.Tensor) -> torch.Tensor:
    """sum_ijk w[i, j, k] bx[p, i] by[p, j] bz[p, k] for (N, N, N) w and (P, N) factors -> (P,)."""
    n = w.shape[0]
    t = (bz @ w.reshape(n * n, n).T).view(-1, n, n)  # (P, i, j)
    return (torch.einsum("pij,pj->pi", t, by) * bx).sum(-1)


def _contract_adjoint(r: torch.Tensor, bx: torch.Tensor, by: torch.Tensor, bz: torch.Tensor) -> torch.Tensor:
    """The adjoint of `_contract`: (P,) -> (N, N, N) sum_p r[p] bx[p, i] by[p, j] bz[p, k]."""
    n = bx.shape[1]
    return (((bx * r[:, None])[:, :, None] * by[:, None, :]).reshape(-1, n * n).T @ bz).reshape(n, n, n)


@dataclass
class FitInfo:
    """How a least-squares fit ended, per link: CG iterations and final relative residual."""

    iterations: list[int]
    residuals: list[float]
    seconds: float


DIRECT_MAX_BASIS = 1000  # up to this many unknowns (N <= 10) the normal equations are formed and factored


def _solve_link(u: torch.Tensor, y: torch.Tensor, n_basis: int, ridge: float, max_iterations: int,
                tolerance: float, start: torch.Tensor | None) -> tuple[torch.Tensor, int, float]:
    """Legendre coefficients (N, N, N) minimising |A c - y|^2 + ridge * n |c|^2: directly (Cholesky of the
    normal equations, float64) for few unknowns, else by Jacobi-preconditioned CG from `start`.
    Returns the coefficients, the CG iterations (0 when direct) and the relative residual."""
    factors = [legendre_basis(u[:, a], n_basis) for a in range(3)]
    lam = ridge * len(u)
    if n_basis**3 <= DIRECT_MAX_BASIS:
        gram = torch.zeros(n_basis**3, n_basis**3, dtype=torch.float64)
        rhs = torch.zeros(n_basis**3, dtype=torch.float64)
        for i in range(0, len(u), 16384):  # design-matrix rows in chunks: (m, N^3) Khatri-Rao products
            fx, fy, fz = (f[i:i + 16384].double() for f in factors)
            a = (fx[:, :, None, None] * fy[:, None, :, None] * fz[:, None, None, :]).flatten(1)
            gram += a.T @ a
            rhs += a.T @ y[i:i + 16384].double()
        gram.diagonal().add_(lam)
        c = torch.cholesky_solve(rhs[:, None], torch.linalg.cholesky(gram))[:, 0]
        rel = float((gram @ c - rhs).norm() / rhs.norm())
        return c.reshape(n_basis, n_basis, n_basis).to(u.dtype), 0, rel

    def normal(c):
        return _contract_adjoint(_contract(c, *factors), *factors) + lam * c

    diag = torch.einsum("pi,pj,pk->ijk", factors[0] ** 2, factors[1] ** 2, factors[2] ** 2) + lam
    rhs = _contract_adjoint(y, *factors)
    c = torch.zeros_like(rhs) if start is None else start.clone()
    r = rhs - normal(c)
    z = r / diag
    p, rz, norm_rhs = z.clone(), (r * z).sum(), rhs.norm()
    it, rel = 0, float(r.norm() / norm_rhs)
    while it < max_iterations and rel > tolerance:
        Ap = normal(p)
        alpha = rz / (p * Ap).sum()
        c, r = c + alpha * p, r - alpha * Ap
        z = r / diag
        rz, rz_old = (r * z).sum(), rz
        p = z + (rz / rz_old) * p
        it, rel = it + 1, float(r.norm() / norm_rhs)
    return c, it, rel


def fit_bernstein(samples, n_basis: int, ridge: float = 1e-7, max_iterations: int = 200, tolerance: float = 1e-3,
                  max_points: int | None = None, warm_start: bool = True, seed: int = 0,
                  dtype: torch.dtype = torch.float32) -> tuple[BernsteinSDF, FitInfo]:
    """Least-squares RDF for every link of a `SampleSet` (all its points, or `max_points` per link).

    Solved per link in `dtype` (float32 by default: the samples are float32, and float64 CG costs about
    twice as much on CPU); with `warm_start` the degree rises 8 -> 16 -> n_basis, each stage
    starting from the last one's coefficients (a lower-degree Legendre expansion is the leading block of
    a higher one), which cuts the CG iterations of the top degree.
    """
    t0 = time.perf_counter()
    model = BernsteinSDF(len(samples.link_names), n_basis)
    stages = [n for n in (8, 16) if warm_start and n < n_basis] + [n_basis]
    gen = torch.Generator().manual_seed(seed)
    iterations, residuals = [], []
    for i in range(len(samples.link_names)):
        rows = torch.nonzero(samples.link == i).flatten()
        if max_points is not None and len(rows) > max_points:
            rows = rows[torch.randperm(len(rows), generator=gen)[:max_points]]
        u, y = samples.points[rows].to(dtype), samples.sdf[rows].to(dtype)
        coeffs, total = None, 0
        for n in stages:
            start = None
            if coeffs is not None:
                start = torch.zeros(n, n, n, dtype=dtype)
                m = coeffs.shape[0]
                start[:m, :m, :m] = coeffs
            coeffs, it, rel = _solve_link(u, y, n, ridge, max_iterations, tolerance, start)
            total += it
        iterations.append(total)
        residuals.append(rel)
        M = _legendre_to_bernstein(n_basis)
        model.weights[i] = torch.einsum("ai,bj,ck,abc->ijk", M, M, M, coeffs.double())
    return model, FitInfo(iterations, residuals, time.perf_counter() - t0)


def _check_conversion(n_basis: int = 24) -> float:
    """Largest |Legendre - M @ Bernstein| on a fine grid (a self-check used by the tests)."""
    t = torch.linspace(0, 1, 257, dtype=torch.float64)
    M = _legendre_to_bernstein(n_basis)
    return float((legendre_basis(2 * t - 1, n_basis) - bernstein_basis(t, n_basis) @ M.T).abs().max())

