"""Shared fixtures: an isolated disk cache and the robots, loaded once per session."""

from __future__ import annotations

import os

import pytest
import torch

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
