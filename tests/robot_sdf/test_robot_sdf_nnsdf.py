"""The NN-SDF baseline (Table III) learns the links: fitted for seconds on the tiny samples, its zero level
set lies near the mesh surfaces and points clear of a surface mostly get the right sign. An untrained
network, or one that ignored its link code, fails these bounds (checked below on the untrained one)."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.robot_sdf.samples import link_signed_distance

pytestmark = pytest.mark.slow  # fits a network for several seconds

STEPS = 800


def _robot_sdf(panda, samples, net):
    from samp.robot_sdf.whole_robot import RobotSDF

    return RobotSDF(panda, net, samples.centres, samples.scales, method="NN-SDF")


@pytest.fixture(scope="module")
def nnsdf(panda, panda_samples, fit):
    from samp.robot_sdf.baselines import NNSDF

    _, samples = panda_samples
    torch.manual_seed(0)
    net, _ = fit(NNSDF(len(samples.link_names), frequencies=4, hidden=[128, 128]), samples, STEPS, lr=2e-3)
    torch.manual_seed(0)
    untrained = NNSDF(len(samples.link_names), frequencies=4, hidden=[128, 128]).eval()
    return _robot_sdf(panda, samples, net.eval()), _robot_sdf(panda, samples, untrained)


def _errors(panda, robot_sdf) -> tuple[float, float, float]:
    """Over all links: median and 90th percentile of |SDF| on the mesh surfaces (m), and the share of points
    more than 1 cm from a surface (inside or out, in the link's padded box) given the wrong sign."""
    surface, wrong, total = [], 0, 0
    for k, name in enumerate(panda.link_names):
        i = robot_sdf.link_names.index(name)
        mesh = panda.geometry[name].mesh
        on = mesh.sample(1000, seed=200 + k)
        lo, hi = mesh.bounds
        box = np.random.default_rng(k).uniform(lo - 0.01, hi + 0.01, size=(3000, 3))
        with torch.no_grad():
            d_on, d_box = (robot_sdf.local_distance(torch.as_tensor(p, dtype=torch.float32),
                                                    torch.full((len(p),), i)).double().numpy() for p in (on, box))
        surface.append(np.abs(d_on))
        truth = link_signed_distance(panda.geometry[name], box)
        clear = np.abs(truth) > 0.01
        wrong += int((np.sign(d_box[clear]) != np.sign(truth[clear])).sum())
        total += int(clear.sum())
    surface = np.concatenate(surface)
    return float(np.median(surface)), float(np.quantile(surface, 0.9)), wrong / total


def test_nnsdf_learns_the_link_surfaces(panda, nnsdf):
    trained, untrained = nnsdf
    """Measured after 800 steps: |SDF| on the surfaces 1.36 mm median, 3.94 mm at the 90th percentile; 0.02 % of
    the points clear of a surface with the wrong sign. The bounds sit at about twice that."""
    median, p90, wrong = _errors(panda, trained)
    assert median < 0.003 and p90 < 0.008 and wrong < 0.01, \
        f"surface median {1e3 * median:.2f} mm, 90 % {1e3 * p90:.2f} mm, wrong sign {100 * wrong:.2f} %"
    u_median, _, u_wrong = _errors(panda, untrained)
    assert u_median > 0.003 or u_wrong > 0.01, f"the bounds must reject an untrained network: {u_median}, {u_wrong}"
