"""RDF and NN-SDF baselines: the Bernstein representation, exact least squares on polynomial targets."""

from __future__ import annotations

import math

import torch

from samp.robot_sdf.baselines import (NNSDF, BernsteinSDF, _check_conversion, bernstein_basis, fit_bernstein,
                                      legendre_basis)
from samp.robot_sdf.samples import SampleSet


def test_bases_are_what_they_claim():
    t = torch.linspace(0, 1, 101, dtype=torch.float64)
    b = bernstein_basis(t, 24)
    torch.testing.assert_close(b.sum(-1), torch.ones_like(t))  # partition of unity
    torch.testing.assert_close(b[:, 3], math.comb(23, 3) * t**3 * (1 - t) ** 20)
    x = torch.linspace(-1, 1, 20001, dtype=torch.float64)
    p = legendre_basis(x, 6)
    gram = (p[:, :, None] * p[:, None, :]).mean(0)  # ~ orthonormal under the uniform measure
    torch.testing.assert_close(gram, torch.eye(6, dtype=torch.float64), atol=2e-3, rtol=0)
    assert _check_conversion(24) < 1e-7 and _check_conversion(8) < 1e-12


def _synthetic_samples(fn, links: int = 2, n: int = 6000, seed: int = 0) -> SampleSet:
    g = torch.Generator().manual_seed(seed)
    u = torch.rand(links * n, 3, generator=g) * 2 - 1
    link = torch.arange(links).repeat_interleave(n)
    return SampleSet(robot="x", robot_asset_hash="0", dataset_id="0", link_names=[f"l{i}" for i in range(links)],
                     centres=torch.zeros(links, 3, dtype=torch.float64), scales=torch.ones(links, dtype=torch.float64),
                     points=u, sdf=fn(u.double(), link).float(), link=link, near=torch.zeros(len(u), dtype=torch.bool))


def test_least_squares_recovers_polynomials_of_the_basis_degree():
    """Targets that are polynomials of degree <= N - 1 per axis are fitted exactly: N = 8 by the direct
    solve, N = 12 by warm-started CG (in float64, so that the check is of the algorithm, not of rounding)."""
    def poly(u, link):
        x, y, z = u.unbind(-1)
        return torch.where(link == 0, 0.3 * x**7 * y - 0.5 * z**3 + 0.1, x * y * z + 0.2 * y**6 * z**7)

    samples = _synthetic_samples(poly)
    for n_basis, kwargs in ((8, {}), (12, {"max_iterations": 400, "tolerance": 1e-11, "warm_start": True,
                                           "dtype": torch.float64})):
        model, info = fit_bernstein(samples, n_basis, ridge=0.0 if n_basis == 8 else 1e-12, **kwargs)
        test = _synthetic_samples(poly, seed=1)
        err = (model(test.points.double(), test.link) - test.sdf.double()).abs().max().item()
        assert err < 2e-5, f"N={n_basis}: max error {err} on a polynomial target ({info})"
        assert model.label == f"RDF (N={n_basis})"


def test_bernstein_model_stays_float64_and_nnsdf_runs():
    m = BernsteinSDF(3, 8).float()
    assert m.weights.dtype == torch.float64
    u, link = torch.rand(10, 3) * 2 - 1, torch.tensor([0, 1, 2, 0, 1, 2, 0, 1, 2, 0])
    assert m(u, link).dtype == torch.float32
    net = NNSDF(3, frequencies=4, hidden=[32, 32])
    out = net(u, link)
    assert out.shape == (10,) and net.label == "NN-SDF"
