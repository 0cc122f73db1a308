"""Robot SDF fixtures: tiny Panda sample sets and a hash-grid SDF trained on them for a few seconds."""

from __future__ import annotations

import pytest
import torch

TINY = {"near_per_link": 6000, "uniform_per_link": 3000}
TEST_ENCODING = {"levels": 8, "log2_table_size": 15, "coarsest": 4, "finest": 512}


@pytest.fixture(scope="session")
def panda(_isolated_cache):
    from samp.robot import load_robot

    return load_robot("panda", dtype=torch.float32)


@pytest.fixture(scope="session")
def panda_samples(panda, tmp_path_factory):
    """(dataset folder, SampleSet) of a tiny sample set in its own registry root."""
    from samp.robot_sdf.samples import SampleConfig, ensure_samples, load_samples

    root = tmp_path_factory.mktemp("robot_sdf_datasets")
    folder = ensure_samples(panda, SampleConfig(**TINY), root, progress=False)
    return folder, load_samples(folder)


def train_hash_sdf(samples, steps: int, seed: int = 0):
    """A `UnifiedHashSDF` fitted in plain torch (no Lightning) to `samples`: (net, final loss)."""
    from samp.robot_sdf.model import UnifiedHashSDF

    torch.manual_seed(seed)
    net = UnifiedHashSDF(len(samples.link_names), encoding=TEST_ENCODING, hidden=[64, 64])
    return fit_sdf(net, samples, steps, seed, lr=5e-3)


def fit_sdf(net, samples, steps: int, seed: int = 0, lr: float = 5e-3):
    """`net` (points (P, 3), link (P,) -> (P,), normalised units) fitted in plain torch to `samples` by mean
    squared error, 512 samples per link a step, the learning rate decaying 50-fold: (net, final loss)."""
    L = len(samples.link_names)
    opt = torch.optim.Adam(net.parameters(), lr=lr, betas=(0.9, 0.99), eps=1e-15)
    sched = torch.optim.lr_scheduler.ExponentialLR(opt, 0.02 ** (1 / steps))
    rows = [torch.nonzero(samples.link == i).flatten() for i in range(L)]
    g = torch.Generator().manual_seed(seed)
    for _ in range(steps):
        b = torch.cat([r[torch.randint(len(r), (512,), generator=g)] for r in rows])
        loss = (net(samples.points[b], samples.link[b]) - samples.sdf[b]).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
    return net.eval(), loss.item()


@pytest.fixture(scope="session")
def trained_sdf(panda, panda_samples):
    """A whole-robot `RobotSDF` from a hash grid trained for a few seconds on the tiny samples."""
    from samp.robot_sdf.whole_robot import RobotSDF

    _, samples = panda_samples
    net, _ = train_hash_sdf(samples, steps=800)
    return RobotSDF(panda, net, samples.centres, samples.scales, method="test hash grid")


@pytest.fixture(scope="session")
def fit():
    """`fit_sdf` as a fixture: test modules take it as an argument instead of importing conftest (which
    `--import-mode=importlib` does not allow)."""
    return fit_sdf


@pytest.fixture(scope="session")
def untrained_sdf(robots, small_robot_sdf):
    """A whole-robot `RobotSDF` for the float64 Panda from the small untrained hash grid with spread tables
    (values far from zero, so many point-link pairs count): seconds to build, for the fast tests."""
    from samp.robot_sdf.artifact import build_net
    from samp.robot_sdf.whole_robot import RobotSDF

    payload = small_robot_sdf(robots["panda"], spread=True)
    info = payload["info"]
    net = build_net(info["net"])
    net.load_state_dict(payload["state_dict"])
    return RobotSDF(robots["panda"], net, torch.tensor(info["centres"]), torch.tensor(info["scales"]), "test",
                    {}).eval()
