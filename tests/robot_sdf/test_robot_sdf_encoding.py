"""The hash-grid encoder: level layout, float32 vs float64, dense vs hashed indexing, gradients."""

from __future__ import annotations

import pytest
import torch

from samp.robot_sdf.encoding import HASH_PRIMES, HashGridEncoding, level_resolutions


def test_level_resolutions_follow_instant_ngp():
    res = level_resolutions(16, 16, 512)
    assert res[0] == 16 and res[-1] == 512 and res == sorted(res)
    b = (512 / 16) ** (1 / 15)
    assert all(r == int(16 * b**level + 1e-9) for level, r in enumerate(res))


def test_hashed_rows_are_the_xor_of_prime_products():
    enc = HashGridEncoding(levels=2, features=2, log2_table_size=8, coarsest=2, finest=32)
    assert enc.hashed == [False, True]  # 3^3 = 27 vertices fit in 256 rows, 33^3 do not
    v = torch.tensor([[0, 0, 0], [1, 2, 3], [31, 7, 30]])
    want = torch.tensor([(x * HASH_PRIMES[0]) ^ (y * HASH_PRIMES[1]) ^ (z * HASH_PRIMES[2]) for x, y, z in v.tolist()]) % 256
    assert torch.equal(enc.vertex_index(v, 1).long(), want)
    dense = torch.tensor([[0, 0, 0], [1, 2, 0], [2, 2, 2]])
    assert torch.equal(enc.vertex_index(dense, 0).long(), dense[:, 0] + 3 * dense[:, 1] + 9 * dense[:, 2])


@pytest.mark.parametrize("interpolation", ["linear", "smoothstep"])
def test_float32_and_float64_agree_in_value_and_gradient(interpolation):
    torch.manual_seed(0)
    enc = HashGridEncoding(levels=6, features=2, log2_table_size=12, coarsest=2, finest=64, interpolation=interpolation,
                           init_scale=0.5)
    x = torch.rand(500, 3, dtype=torch.float64)
    enc64 = HashGridEncoding(levels=6, features=2, log2_table_size=12, coarsest=2, finest=64, interpolation=interpolation)
    enc64.load_state_dict(enc.state_dict())
    enc64.double()
    x32, x64 = x.float().requires_grad_(), x.clone().requires_grad_()
    y32, y64 = enc(x32), enc64(x64)
    torch.testing.assert_close(y32.double(), y64, rtol=0, atol=1e-5)
    w = torch.randn_like(y64)
    (y32 * w.float()).sum().backward()
    (y64 * w).sum().backward()
    torch.testing.assert_close(x32.grad.double(), x64.grad, rtol=1e-3, atol=1e-3)
    for a, b in zip(enc.tables, enc64.tables):
        torch.testing.assert_close(a.grad.double(), b.grad, rtol=0, atol=1e-5)


def test_dense_and_hashed_levels_agree_when_nothing_collides():
    """A level small enough to be dense, stored hashed instead into a table too large for collisions at
    these vertices, gives the same features once its table holds the same values at the hashed rows."""
    torch.manual_seed(1)
    dense = HashGridEncoding(levels=1, features=3, log2_table_size=20, coarsest=7, finest=7, init_scale=1.0)
    hashed = HashGridEncoding(levels=1, features=3, log2_table_size=20, coarsest=7, finest=7, dense=False)
    assert dense.hashed == [False] and hashed.hashed == [True]
    grid = torch.stack(torch.meshgrid(*[torch.arange(8)] * 3, indexing="ij"), -1).reshape(-1, 3)
    rows_d, rows_h = dense.vertex_index(grid, 0).long(), hashed.vertex_index(grid, 0).long()
    assert len(set(rows_h.tolist())) == len(grid), "test premise: no collisions among these 512 vertices"
    with torch.no_grad():
        hashed.tables[0][rows_h] = dense.tables[0][rows_d]
    x = torch.rand(300, 3, dtype=torch.float32).requires_grad_()
    xh = x.detach().clone().requires_grad_()
    torch.testing.assert_close(dense(x), hashed(xh), rtol=0, atol=1e-6)
    dense(x).sum().backward()
    hashed(xh).sum().backward()
    torch.testing.assert_close(x.grad, xh.grad, rtol=0, atol=1e-5)


def test_bad_points_are_refused():
    enc = HashGridEncoding(levels=2, log2_table_size=8, finest=8)
    with pytest.raises(ValueError, match=r"points must have shape \(P, 3\)"):
        enc(torch.rand(4, 2))
