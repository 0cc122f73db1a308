"""Multiresolution hash-grid encoding (Instant-NGP, Mueller et al. 2022) in pure torch.

A point x in [0, 1]^3 is looked up in L grids of increasing resolution. Level l has
res_l = floor(N_min * b^l) cells per axis, b = exp((ln N_max - ln N_min) / (L - 1)), and (res_l + 1)^3
vertices. A level whose vertices fit into the table size T is stored densely (one row per vertex,
row x + y (R+1) + z (R+1)^2); a finer level is hashed into T rows with
h(x, y, z) = (x * 1) XOR (y * 2654435761) XOR (z * 805459861) mod T. The 8 corner features of the
point's cell are blended with trilinear weights, linear or smoothstep (w = f^2 (3 - 2 f), whose
derivative vanishes on cell faces), and the L feature vectors are concatenated: (P, 3) -> (P, L * F).

Products are taken in int64 and masked to the low bits (T is a power of two): the low 32 bits of an
int64 product equal those of the uint32 product of the CUDA implementation, so the rows are
Instant-NGP's. The combined rows are int32 (half the memory of int64).
Each level has its own table parameter and is processed in turn: a level's temporaries are small
enough to stay in cache, which made the CPU forward about 3x faster than one pass over all levels,
and a level's gradient is only as large as its table. Everything is plain torch, so it runs on CPU
and CUDA, in float32 and float64, with gradients for the points and the tables (first order only).
"""

from __future__ import annotations

import math

import torch
from torch import nn

__all__ = ["HASH_PRIMES", "INTERPOLATIONS", "HashGridEncoding", "level_resolutions"]

HASH_PRIMES = (1, 2654435761, 805459861)
# Without autograd, points are encoded in one pass over all levels (`_fused`), this many at a time: a
# policy step's few hundred point-link pairs would cost the per-level loop's Python overhead, not
# arithmetic, and chunks of this size keep the pass's temporaries in cache.
FUSED_CHUNK = 1 << 11
INTERPOLATIONS = ("linear", "smoothstep")


def level_resolutions(levels: int, coarsest: int, finest: int) -> list[int]:
    """Cells per axis of each level: floor(N_min * b^l), b the growth factor between N_min and N_max."""
    if levels < 1 or coarsest < 1 or finest < coarsest:
        raise ValueError(f"need levels >= 1 and 1 <= coarsest <= finest, got levels={levels}, "
                         f"coarsest={coarsest}, finest={finest}")
    if levels == 1:
        return [coarsest]
    growth = math.exp((math.log(finest) - math.log(coarsest)) / (levels - 1))
    # The small epsilon keeps floor(N_min * b^(L-1)) from landing one below N_max by rounding.
    return [int(math.floor(coarsest * growth**level + 1e-9)) for level in range(levels)]


class HashGridEncoding(nn.Module):
    """(P, 3) points in [0, 1]^3 -> (P, levels * features) features.

    Args:
        levels: number of resolution levels L.
        features: features per level F.
        log2_table_size: T = 2**log2_table_size rows per hashed level (dense levels use fewer), at most 2^30.
        coarsest, finest: cells per axis of the first and last level (N_min, N_max).
        interpolation: "linear" or "smoothstep".
        dense: store levels that fit into T densely (Instant-NGP's choice); False hashes every level.
        init_scale: table entries start uniform in [-init_scale, init_scale] (Instant-NGP: 1e-4).

    Attributes:
        tables: one (rows_l, F) parameter per level; `hashed[l]` says how level l is indexed.

    Points outside [0, 1]^3 are clamped onto it.
    """

    def __init__(self, levels: int = 32, features: int = 2, log2_table_size: int = 19, coarsest: int = 1,
                 finest: int = 2048, interpolation: str = "smoothstep", dense: bool = True,
                 init_scale: float = 1e-4):
        super().__init__()
        if interpolation not in INTERPOLATIONS:
            raise ValueError(f"interpolation must be one of {INTERPOLATIONS}, got {interpolation!r}")
        if not 1 <= log2_table_size <= 30:
            raise ValueError(f"log2_table_size must be in [1, 30], got {log2_table_size}")
        if features < 1:
            raise ValueError(f"features must be >= 1, got {features}")
        self.levels, self.features, self.interpolation = levels, features, interpolation
        self.table_size = 1 << log2_table_size
        self.resolutions = level_resolutions(levels, coarsest, finest)
        self.hashed = [not (dense and (res + 1) ** 3 <= self.table_size) for res in self.resolutions]
        self.tables = nn.ParameterList([
            nn.Parameter(torch.empty(self.table_size if h else (res + 1) ** 3, features).uniform_(-init_scale, init_scale))
            for res, h in zip(self.resolutions, self.hashed)])
        self.register_buffer("primes", torch.tensor(HASH_PRIMES, dtype=torch.long), persistent=False)

    @property
    def out_dim(self) -> int:
        return self.levels * self.features

    @property
    def num_params(self) -> int:
        return sum(t.numel() for t in self.tables)

    def _axis_terms(self, corner: torch.Tensor, level: int) -> torch.Tensor:
        """(3, ...) int64 vertex coordinates, axis first -> (3, ...) int32 per-axis terms, each in [0, T):
        a vertex's row is their sum (dense) or XOR (hashed)."""
        shape = (3,) + (1,) * (corner.ndim - 1)
        if self.hashed[level]:
            return ((corner * self.primes.view(shape)) & (self.table_size - 1)).to(torch.int32)
        stride = self.resolutions[level] + 1
        return (corner * corner.new_tensor([1, stride, stride * stride]).view(shape)).to(torch.int32)

    def vertex_index(self, corner: torch.Tensor, level: int) -> torch.Tensor:
        """(V, 3) int64 vertex coordinates of one level -> (V,) rows of `tables[level]` (for tests and
        inspection; `forward` builds the same rows for the 8 corners of every point)."""
        t = self._axis_terms(corner.T, level)
        return (t[0] ^ t[1] ^ t[2]) if self.hashed[level] else (t[0] + t[1] + t[2])

    def _level(self, xt: torch.Tensor, level: int) -> torch.Tensor:
        """(3, P) points, axis first (each axis contiguous: fast elementwise ops) -> (P, F) features."""
        res = self.resolutions[level]
        pos = xt * res
        # A point on the upper face uses the last cell, with weight 1 on its upper corners.
        base = pos.detach().floor().clamp(max=max(res - 1, 0))
        w1 = pos - base  # (3, P): weight of each axis's upper corner
        if self.interpolation == "smoothstep":
            w1 = w1 * w1 * (3 - 2 * w1)
        w = (1 - w1, w1)
        lo = base.long()
        t = (self._axis_terms(lo, level), self._axis_terms(lo + 1, level))
        combine = (lambda a, b, c: a ^ b ^ c) if self.hashed[level] else (lambda a, b, c: a + b + c)
        corners = [(a, b, c) for a in (0, 1) for b in (0, 1) for c in (0, 1)]
        rows = [combine(t[a][0], t[b][1], t[c][2]) for a, b, c in corners]  # 8 x (P,)
        weights = [w[a][0] * w[b][1] * w[c][2] for a, b, c in corners]  # 8 x (P,)
        table = self.tables[level]
        if torch.is_grad_enabled() and (table.requires_grad or xt.requires_grad):
            return _Interpolate.apply(table, torch.stack(rows), torch.stack(weights))
        out = weights[0][:, None] * table.index_select(0, rows[0])  # no autograd: skip the stacking
        for r, wc in zip(rows[1:], weights[1:]):
            out += wc[:, None] * table.index_select(0, r)
        return out

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        """x (P, 3) in [0, 1]^3 -> (P, levels * features)."""
        if x.ndim != 2 or x.shape[-1] != 3:
            raise ValueError(f"points must have shape (P, 3), got {tuple(x.shape)}")
        xt = x.clamp(0, 1).to(self.tables[0].dtype).T.contiguous()  # (3, P)
        if not torch.is_grad_enabled():
            return torch.cat([self._fused(xt[:, i:i + FUSED_CHUNK]) for i in range(0, xt.shape[1], FUSED_CHUNK)]) \
                if xt.shape[1] > FUSED_CHUNK else self._fused(xt)
        return torch.cat([self._level(xt, level) for level in range(self.levels)], dim=1)

    def _packed(self) -> dict[str, torch.Tensor]:
        """Every level's constants side by side, and the tables stacked into one, for `_fused`; rebuilt
        when a table changes (an optimizer step or `load_state_dict` bumps its version) or moves."""
        key = tuple((t.data_ptr(), t._version, t.dtype) for t in self.tables)
        if getattr(self, "_pack_key", None) != key:
            with torch.inference_mode(False):  # plain tensors, usable in and out of inference mode
                self._pack = self._pack_tables()
            self._pack_key = key
        return self._pack

    def _pack_tables(self) -> dict:
        """`_packed`'s contents, built from the current tables."""
        device, dtype = self.tables[0].device, self.tables[0].dtype
        rows = [len(t) for t in self.tables]
        res = torch.tensor(self.resolutions, device=device)
        dense_stride = torch.stack([torch.ones_like(res), res + 1, (res + 1) ** 2], dim=1)  # (L, 3)
        hashed = torch.tensor(self.hashed, device=device)
        table = torch.cat([t.detach() for t in self.tables])
        pack = {
            "table": table,
            "offset": torch.tensor([0, *rows[:-1]], device=device).cumsum(0).int()[:, None],  # (L, 1)
            "res": res.to(dtype)[:, None, None],  # (L, 1, 1)
            "top": (res - 1).clamp(min=0).to(dtype)[:, None, None],
            # per-axis multipliers: the hash primes, or the dense strides; and the mask of the hash
            "mult": torch.where(hashed[:, None], self.primes[None], dense_stride)[:, :, None],  # (L, 3, 1)
            "mask": torch.where(hashed, self.table_size - 1, -1)[:, None, None],  # (L, 1, 1): -1 keeps all bits
            "dense": self.hashed.index(True) if any(self.hashed) else self.levels,  # dense levels come first
        }
        if self.features * table.element_size() == 8:  # a row is 8 bytes: gather rows as one int64 each
            pack["rows64"] = table.view(torch.int64).view(-1)
        return pack

    def _fused(self, xt: torch.Tensor) -> torch.Tensor:
        """`forward` for all levels at once, without autograd: the same rows and weights as `_level`, in
        about 25 operations instead of about 40 per level (what a policy step's few hundred points cost)."""
        k = self._packed()
        pos = xt[None] * k["res"]  # (L, 3, P)
        base = pos.floor().minimum(k["top"])
        w1 = pos - base
        if self.interpolation == "smoothstep":
            w1 = w1 * w1 * (3 - 2 * w1)
        lo = base.long()
        # (2, L, 3, P): each axis's term for the lower and the upper corner; below 2^31 (a row index)
        terms = (torch.stack([lo, lo + 1]) * k["mult"] & k["mask"]).int()
        tx, ty, tz = terms[:, None, None, :, 0], terms[None, :, None, :, 1], terms[None, None, :, :, 2]  # (2,2,2,L,P)
        d = k["dense"]  # levels [0, d) are dense (rows add up), the rest hashed (rows XOR)
        rows = torch.cat([tx[..., :d, :] + ty[..., :d, :] + tz[..., :d, :],
                          tx[..., d:, :] ^ ty[..., d:, :] ^ tz[..., d:, :]], dim=3) + k["offset"]
        w = torch.stack([1 - w1, w1])  # (2, L, 3, P)
        weights = w[:, None, None, :, 0] * w[None, :, None, :, 1] * w[None, None, :, :, 2]  # (2, 2, 2, L, P)
        L, P, F = pos.shape[0], pos.shape[2], self.features
        if "rows64" in k:  # one 8-byte gather per corner is several times faster than index_select of (., 2) rows
            values = k["rows64"].index_select(0, rows.view(-1)).view(k["table"].dtype).view(8, L, P, F)
        else:
            values = k["table"].index_select(0, rows.view(-1)).view(8, L, P, F)
        out = (weights.view(8, L, P, 1) * values).sum(0)  # (L, P, F)
        return out.transpose(0, 1).reshape(P, L * F)

    def extra_repr(self) -> str:
        return (f"levels={self.levels}, features={self.features}, table_size={self.table_size}, "
                f"resolutions={self.resolutions[0]}..{self.resolutions[-1]}, dense_levels={self.hashed.count(False)}, "
                f"interpolation={self.interpolation}, params={self.num_params}")


class _Interpolate(torch.autograd.Function):
    """out[p] = sum_c weights[c, p] * table[rows[c, p]]: (T, F), (8, P) int, (8, P) -> (P, F).

    Written out so that the backward is one `index_add_` per level: autograd's backward of a gather
    (`embedding_dense_backward`) was about 8x slower on CPU, and one per corner would clear the
    level's whole gradient table eight times.
    """

    @staticmethod
    def forward(ctx, table: torch.Tensor, rows: torch.Tensor, weights: torch.Tensor) -> torch.Tensor:
        ctx.save_for_backward(table, rows, weights)
        out = weights[0, :, None] * table.index_select(0, rows[0])
        for c in range(1, rows.shape[0]):
            out += weights[c, :, None] * table.index_select(0, rows[c])
        return out

    @staticmethod
    def backward(ctx, grad: torch.Tensor):
        table, rows, weights = ctx.saved_tensors
        grad_table = grad_weights = None
        if ctx.needs_input_grad[0]:
            per_corner = weights[:, :, None] * grad[None]  # (8, P, F)
            # int64 rows: CPU index_add_ was ~17x slower with an int32 index (torch 2.13).
            grad_table = torch.zeros_like(table).index_add_(0, rows.reshape(-1).long(), per_corner.reshape(-1, table.shape[1]))
        if ctx.needs_input_grad[2]:
            grad_weights = torch.stack([(table.index_select(0, r) * grad).sum(-1) for r in rows])  # (8, P)
        return grad_table, None, grad_weights
