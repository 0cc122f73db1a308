"""Where the environment encoder's features are read (issue 18): a feature must be sampled where it was
computed. A box-filter encoder (every conv weight equal, no bias, no normalisation) responds to a single
planted obstacle cell symmetrically around that cell, so the centre of mass of the sampled response along
each axis is the oracle: it must sit within half an input cell of the planted cell."""

from __future__ import annotations

import pytest
import torch

from samp.policy.network import EnvEncoder, PolicyConfig, SAMPNet, sample_by_scene

BOUNDS = ((-1.0, -1.0, 0.05), (1.0, 1.0, 1.25))
N_ES = (39, 40, 70, 100, 130, 160)  # every n_e the experiments offer (samp_n40 ... samp_n160), and an odd one


def _box_encoder(registration: str) -> EnvEncoder:
    enc = EnvEncoder(1, norm="none", registration=registration)
    conv = enc.net[0]
    with torch.no_grad():
        conv.weight.fill_(1.0 / 27)
        conv.bias.zero_()
    return enc.eval()


def _response_offsets(enc: EnvEncoder, n_e: int, cell: tuple[int, int, int]) -> list[float]:
    """Per axis, (centre of mass of the sampled response along the line through `cell`) - cell, in cells."""
    grid = torch.zeros(1, n_e, n_e, n_e)
    grid[(0, *cell)] = 1.0
    with torch.no_grad():
        feats = enc(grid)
    lo, hi = (torch.tensor(b) for b in BOUNDS)
    anchors = [torch.linspace(float(lo[a]), float(hi[a]), n_e) for a in range(3)]
    centre = torch.stack([anchors[a][cell[a]] for a in range(3)])
    box = enc.feature_bounds(BOUNDS, n_e, feats.shape[-1])
    offsets = []
    for axis in range(3):
        points = centre.repeat(n_e, 1)
        points[:, axis] = anchors[axis]
        r = sample_by_scene(feats, torch.zeros(1, dtype=torch.long), points[None], box)[0, 0]  # (n_e,)
        assert r.sum() > 0, "the planted obstacle left no response along its own axis"
        offsets.append(float((r * torch.arange(n_e)).sum() / r.sum()) - cell[axis])
    return offsets


@pytest.mark.parametrize("n_e", N_ES)
def test_features_are_read_where_they_were_computed(n_e):
    enc = _box_encoder("centres")
    # Both parities, near each border and in the middle (a wrong stride or offset shows most at the borders).
    # A cell's response spans up to three cells each side; within three cells of the faces part of it falls
    # beyond the outermost feature cells, where sampling repeats their values, so those cells are left out.
    cells = (4, 5, n_e // 2, n_e // 2 + 1, n_e - 7, n_e - 6)
    for i, c in enumerate(cells):
        offsets = _response_offsets(enc, n_e, (c, cells[-1 - i], cells[(i + 2) % len(cells)]))
        assert max(abs(o) for o in offsets) <= 0.5, (n_e, c, offsets)


def test_bounds_registration_misplaces_features():
    """The convention of checkpoints trained before the fix reads features up to two cells away; the check
    above would have caught it (this is the defect the registration fix removes)."""
    enc = _box_encoder("bounds")
    worst = max(max(abs(o) for o in _response_offsets(enc, 40, (c, c, c))) for c in (4, 5, 20, 33, 34))
    assert worst > 0.9


def test_feature_bounds_are_the_cell_centres():
    """Hand-computed: n_e = 40 over [-1, 1] has anchors every 2/39 m; 19 features on anchors 1, 3, ..., 37."""
    enc = EnvEncoder(4, registration="centres")
    feats = enc(torch.zeros(1, 40, 40, 40))
    assert feats.shape[-1] == 19
    lo, hi = enc.feature_bounds(BOUNDS, 40, 19)
    assert lo[0] == pytest.approx(-1 + 2 / 39) and hi[0] == pytest.approx(-1 + 37 * 2 / 39)
    assert lo[2] == pytest.approx(0.05 + 1.2 / 39) and hi[2] == pytest.approx(0.05 + 37 * 1.2 / 39)


@pytest.mark.parametrize("norm", ["batch", "group", "none"])
def test_norm_options_and_scene_independence(norm):
    """GroupNorm and no normalisation give each scene's features independently of the other scenes in the
    batch, in training mode too; BatchNorm in training mode does not (its statistics are the batch's)."""
    torch.manual_seed(0)
    enc = EnvEncoder(4, norm=norm).train()
    a, b = torch.randn(1, 20, 20, 20), torch.randn(1, 20, 20, 20) * 3 + 1
    alone = enc(a)
    together = enc(torch.cat([a, b]))[:1]
    same = torch.allclose(alone, together, atol=1e-5)
    assert same == (norm != "batch")


def test_bad_options_are_refused():
    with pytest.raises(ValueError, match="model.norm"):
        EnvEncoder(4, norm="layer")
    with pytest.raises(ValueError, match="model.registration"):
        EnvEncoder(4, registration="corners")
    net = SAMPNet(PolicyConfig(num_points=8))
    feats = net.encode_scenes(torch.zeros(1, 10, 10, 10))
    with pytest.raises(ValueError, match="needs n_e"):
        net(torch.zeros(1, 7), torch.zeros(1, 7), torch.zeros(1, 8, 3), torch.zeros(1, 8), feats,
            torch.zeros(1, dtype=torch.long), BOUNDS)
