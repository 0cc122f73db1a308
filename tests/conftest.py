"""Shared fixtures: an isolated disk cache, the robots (loaded once per session) and a small robot SDF.

The suite runs MKL on its CPU-independent code path (`samp.data.lifecycle.REPRODUCIBLE_MKL`, set before
torch makes its first MKL call, and inherited by every process a test starts): tests that pin bytes (a
generated dataset's digests) or compare two code paths bit for bit (the robot SDF's needed points against the
full query, which MKL computes with different kernels for different shapes on some CPUs) then hold on every
x86 CPU, not only on the one they were written on.

Tracking in MLflow is off for the suite (`SAMP_TRACKING_URI=off`, inherited by every process a test starts):
importing MLflow and creating a store cost seconds in each training process, and a developer's own
`SAMP_TRACKING_URI` must not receive test runs. The tests of tracking turn it back on for their processes
(tests/runs/test_runs_tracking.py, test_runs_resume.py, test_runs_submitit.py, tests/e2e).
"""

from __future__ import annotations

import os

import pytest
import torch

from samp.data.lifecycle import reproducible_mkl

reproducible_mkl()  # importing torch makes no MKL call; this is before the first one (module docstring)
os.environ["SAMP_TRACKING_URI"] = "off"  # (module docstring)

ROBOTS = ["panda", "iiwa", "xarm6"]


@pytest.fixture(scope="session", autouse=True)
def _isolated_cache(tmp_path_factory):
    """Every test session samples robot points afresh into its own cache folder."""
    old = os.environ.get("SAMP_CACHE_DIR")
    os.environ["SAMP_CACHE_DIR"] = str(tmp_path_factory.mktemp("samp_cache"))
    yield
    if old is None:
        os.environ.pop("SAMP_CACHE_DIR", None)
    else:
        os.environ["SAMP_CACHE_DIR"] = old


@pytest.fixture(scope="session")
def robots(_isolated_cache):
    from samp.robot import load_robot

    return {name: load_robot(name, dtype=torch.float64) for name in ROBOTS}


@pytest.fixture(params=ROBOTS)
def robot(request, robots):
    return robots[request.param]


@pytest.fixture(scope="session")
def small_robot_sdf():
    """(robot, spread=False) -> a small untrained hash-grid robot SDF in the artifact format (a policy
    checkpoint's robot_sdf payload). `spread` draws its hash tables from U(-1, 1), so that its values, and
    the pairs a robot-point query must evaluate, are far from zero."""
    import torch

    from samp.robot_sdf.artifact import describe, net_spec
    from samp.robot_sdf.model import UnifiedHashSDF
    from samp.robot_sdf.samples import link_normalisation

    def make(robot, spread: bool = False) -> dict:
        torch.manual_seed(0)
        kwargs = {"num_links": len(robot.link_names), "encoding": {"levels": 4, "log2_table_size": 10, "finest": 64},
                  "hidden": [16]}
        net = UnifiedHashSDF(**kwargs)
        if spread:
            with torch.no_grad():
                for table in net.encoder.tables:
                    table.uniform_(-1, 1)
        centres, scales = link_normalisation(robot, 0.02)
        info = describe(robot, net_spec(net, kwargs), "test", torch.tensor(centres), torch.tensor(scales))
        return {"info": info, "state_dict": net.state_dict(), "artifact_id": "test"}

    return make
