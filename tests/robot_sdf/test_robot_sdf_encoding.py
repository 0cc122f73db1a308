"""The hash-grid encoder against independent oracles: Instant-NGP's hash in uint32 arithmetic, exact
reproduction of linear functions, float32 vs float64, dense vs hashed storage, finite differences."""

from __future__ import annotations

import math

import pytest
import torch

from samp.robot_sdf.encoding import HashGridEncoding, level_resolutions


def _random_points(n: int, seed: int = 0, dtype=torch.float64) -> torch.Tensor:
    return torch.rand(n, 3, generator=torch.Generator().manual_seed(seed), dtype=dtype)


def test_level_resolutions_follow_the_geometric_growth():
    res = level_resolutions(16, 16, 2048)
    growth = math.exp((math.log(2048) - math.log(16)) / 15)
    assert res[0] == 16 and res[-1] == 2048, res
    assert res == [int(math.floor(16 * growth**l + 1e-9)) for l in range(16)]
    with pytest.raises(ValueError, match="coarsest"):
        level_resolutions(4, 8, 4)


def test_hash_matches_uint32_reference():
    """Rows of a hashed level equal (x * 1 ^ y * 2654435761 ^ z * 805459861) mod 2^32 mod T, computed
    here with Python integers."""
    enc = HashGridEncoding(levels=2, log2_table_size=12, coarsest=64, finest=512)
    assert enc.hashed == [True, True]
    g = torch.Generator().manual_seed(1)
    corners = torch.randint(0, 513, (500, 3), generator=g)
    got = enc.vertex_index(corners, 1).tolist()
    want = [((x * 1) ^ (y * 2654435761 % 2**32) ^ (z * 805459861 % 2**32)) % 2**32 % 4096 for x, y, z in corners.tolist()]
    assert got == want


def test_dense_level_indexes_every_vertex_once():
    enc = HashGridEncoding(levels=1, log2_table_size=12, coarsest=8, finest=8)
    assert enc.hashed == [False] and enc.tables[0].shape[0] == 9**3
    grid = torch.cartesian_prod(*[torch.arange(9)] * 3)
    rows = enc.vertex_index(grid, 0)
    assert sorted(rows.tolist()) == list(range(9**3))
    # row x + 9 y + 81 z (the grid's second vertex is (0, 0, 1))
    assert rows[1].item() == 81 and enc.vertex_index(torch.tensor([[1, 0, 0], [0, 1, 0]]), 0).tolist() == [1, 9]


def _fill_linear(enc: HashGridEncoding, level: int, coeff: torch.Tensor) -> None:
    """Set a dense level's vertex features to the linear function coeff (F, 4) . (x, y, z, 1) of the vertex position."""
    res = enc.resolutions[level]
    grid = torch.cartesian_prod(*[torch.arange(res + 1)] * 3)
    pos = torch.cat([grid.double() / res, torch.ones(len(grid), 1, dtype=torch.float64)], dim=1)
    with torch.no_grad():
        enc.tables[level][enc.vertex_index(grid, level)] = (pos @ coeff.T).to(enc.tables[level].dtype)


def test_linear_interpolation_reproduces_linear_functions():
    enc = HashGridEncoding(levels=1, features=2, log2_table_size=16, coarsest=7, finest=7, interpolation="linear").double()
    coeff = torch.tensor([[0.3, -1.2, 0.7, 0.1], [2.0, 0.5, -0.4, -1.0]], dtype=torch.float64)
    _fill_linear(enc, 0, coeff)
    x = _random_points(1000)
    want = torch.cat([x, torch.ones(len(x), 1, dtype=torch.float64)], dim=1) @ coeff.T
    torch.testing.assert_close(enc(x), want, atol=1e-12, rtol=0)
    x.requires_grad_(True)
    grad = torch.autograd.grad(enc(x)[:, 0].sum(), x)[0]
    torch.testing.assert_close(grad, coeff[0, :3].expand_as(grad), atol=1e-10, rtol=0)


def test_smoothstep_keeps_vertex_values_and_is_flat_on_cell_faces():
    enc = HashGridEncoding(levels=1, features=1, log2_table_size=16, coarsest=4, finest=4).double()
    vertex = torch.tensor([[1.0, 2.0, 3.0]], dtype=torch.float64) / 4
    row = enc.vertex_index(torch.tensor([[1, 2, 3]]), 0)
    torch.testing.assert_close(enc(vertex)[0, 0], enc.tables[0][row[0], 0].detach())
    x = torch.tensor([[0.25, 0.3, 0.6]], dtype=torch.float64, requires_grad=True)  # on a face normal to x
    grad = torch.autograd.grad(enc(x).sum(), x)[0]
    assert abs(grad[0, 0].item()) < 1e-12, f"smoothstep weight should have zero slope across a face, got {grad}"


def test_float32_and_float64_agree():
    enc64 = HashGridEncoding(levels=8, log2_table_size=12, coarsest=2, finest=256, init_scale=0.5).double()
    enc32 = HashGridEncoding(levels=8, log2_table_size=12, coarsest=2, finest=256)
    enc32.load_state_dict({k: v.float() for k, v in enc64.state_dict().items()})
    x64 = _random_points(2000, seed=3).requires_grad_(True)
    x32 = x64.detach().float().requires_grad_(True)
    out64, out32 = enc64(x64), enc32(x32)
    torch.testing.assert_close(out32.double(), out64.detach(), atol=1e-4, rtol=0)
    w = torch.randn(out64.shape[1], dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    g64 = torch.autograd.grad((out64 @ w).sum(), x64)[0]
    g32 = torch.autograd.grad((out32 @ w.float()).sum(), x32)[0]
    # float32 positions carry ~1e-7 * res error, so weights differ slightly; gradients scale with res.
    err = (g32.double() - g64).abs().max().item()
    assert err < 1e-2 * g64.abs().max().item(), f"float32 gradient differs by {err}"


def test_dense_and_hashed_levels_agree_where_both_apply():
    """A level of resolution 10 (1331 vertices) stored densely and hashed into 2^17 rows (the smallest
    table where the Instant-NGP hash has no collision among these vertices), the hashed rows filled from
    the dense ones: same features and the same gradients for points and tables."""
    dense = HashGridEncoding(levels=1, log2_table_size=17, coarsest=10, finest=10, init_scale=1.0).double()
    hashed = HashGridEncoding(levels=1, log2_table_size=17, coarsest=10, finest=10, dense=False).double()
    assert dense.hashed == [False] and hashed.hashed == [True]
    grid = torch.cartesian_prod(*[torch.arange(11)] * 3)
    d_rows, h_rows = dense.vertex_index(grid, 0), hashed.vertex_index(grid, 0)
    assert len(set(h_rows.tolist())) == len(grid), "hash collisions among this level's vertices"
    with torch.no_grad():
        hashed.tables[0][h_rows] = dense.tables[0][d_rows]
    x = _random_points(3000, seed=5)
    xd, xh = x.clone().requires_grad_(True), x.clone().requires_grad_(True)
    od, oh = dense(xd), hashed(xh)
    torch.testing.assert_close(oh, od, atol=1e-14, rtol=0)
    (od.square().sum()).backward()
    (oh.square().sum()).backward()
    torch.testing.assert_close(xh.grad, xd.grad, atol=1e-12, rtol=0)
    torch.testing.assert_close(hashed.tables[0].grad[h_rows], dense.tables[0].grad[d_rows], atol=1e-12, rtol=0)


def test_gradient_matches_finite_differences():
    enc = HashGridEncoding(levels=4, log2_table_size=10, coarsest=3, finest=40, init_scale=1.0).double()
    w = torch.randn(enc.out_dim, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    x = _random_points(50, seed=7).requires_grad_(True)
    grad = torch.autograd.grad(enc(x) @ w, x, grad_outputs=torch.ones(50, dtype=torch.float64))[0]
    h = 1e-7
    for axis in range(3):
        step = torch.zeros(3, dtype=torch.float64)
        step[axis] = h
        with torch.no_grad():
            fd = ((enc(x + step) - enc(x - step)) @ w) / (2 * h)
        torch.testing.assert_close(grad[:, axis], fd, atol=1e-5, rtol=1e-5)


def test_points_of_the_wrong_shape_are_refused():
    enc = HashGridEncoding(levels=2, log2_table_size=8, coarsest=2, finest=4)
    with pytest.raises(ValueError, match=r"shape \(P, 3\)"):
        enc(torch.rand(4, 2))
    with pytest.raises(ValueError, match="interpolation"):
        HashGridEncoding(interpolation="cubic")


@pytest.mark.gpu
def test_cpu_and_cuda_agree():
    if not torch.cuda.is_available():
        pytest.skip("no CUDA device")
    enc = HashGridEncoding(levels=8, log2_table_size=14, coarsest=2, finest=512, init_scale=0.5)
    x = _random_points(5000, seed=8, dtype=torch.float32)
    cpu = enc(x)
    gpu = enc.to("cuda")(x.cuda()).cpu()
    torch.testing.assert_close(gpu, cpu, atol=1e-5, rtol=1e-5)
