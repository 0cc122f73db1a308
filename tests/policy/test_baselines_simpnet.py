"""SIMPNet-style sampler: the network's shapes, the learned proposal distribution against its definition,
and planning inside OMPL with the learned sampler installed, checked by the evaluation's own collision
checks, after a reload from a checkpoint."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from samp.policy.baselines.simpnet import SIMPNetConfig, SIMPNetNet
from samp.policy.baselines.simpnet_planner import LearnedSampler, SIMPNetPlanConfig

SMALL = {"channels": [4, 8], "cells": 2, "width": 16, "heads": 2, "rounds": 1, "dropout": 0.1}


def test_network_shapes_and_stay_at_first():
    net = SIMPNetNet(SIMPNetConfig(**SMALL)).eval()
    tokens = net.encode(torch.randn(2, 16, 16, 16))
    assert tokens.shape == (2, 8, 16)
    u = torch.rand(2, 7) * 2 - 1
    assert torch.equal(net(tokens, u, -u), u), "the zero-initialised readout should propose no step"
    with pytest.raises(ValueError, match="expects tokens"):
        net(tokens, u[:, :6], u[:, :6])
    with pytest.raises(ValueError, match="multiple of heads"):
        SIMPNetConfig(width=10, heads=4)


def test_learned_sampler_draws_near_its_proposals_and_within_the_distance():
    limits = np.array([[-1.0, 1.0]] * 3)
    pool = np.array([[0.5, 0.5, 0.5], [0.9, 0.9, 0.9]])
    sampler = LearnedSampler(pool, limits, fraction=1.0, noise=0.0, rng=np.random.default_rng(0))
    near = np.zeros(3)
    draws = np.stack([sampler.sample_near(near, 0.3) for _ in range(50)])
    # No proposal within 0.3: a step of exactly 0.3 toward one of them, i.e. along the diagonal.
    assert np.allclose(np.linalg.norm(draws, axis=1), 0.3) and np.allclose(draws, draws[:, :1])
    assert np.allclose(sampler.sample_near(np.full(3, 0.45), 0.2), 0.5), "a proposal within reach is drawn as is"
    uniform = LearnedSampler(pool, limits, fraction=0.0, noise=0.0, rng=np.random.default_rng(1))
    free = np.stack([uniform.sample_near(near, 0.3) for _ in range(200)])
    assert (np.linalg.norm(free, axis=1) <= 0.3 + 1e-12).all() and uniform.drawn == {"learned": 0, "uniform": 200}
    with pytest.raises(ValueError, match="learned_fraction"):
        SIMPNetPlanConfig(learned_fraction=1.5)


def test_plans_inside_ompl_with_the_learned_sampler_after_a_reload(tiny, tiny_datamodule, tmp_path):
    import pytorch_lightning as pl

    from samp.data import open_dataset
    from samp.eval import evaluate, problems_from_dataset
    from samp.policy import load_policy
    from samp.policy.baselines.simpnet_system import SIMPNetSystem

    dm = tiny_datamodule(16)
    system = SIMPNetSystem(robot="panda", model=SMALL)
    trainer = pl.Trainer(max_steps=2, logger=False, enable_checkpointing=False, enable_progress_bar=False,
                         enable_model_summary=False, num_sanity_val_steps=0, limit_val_batches=0)
    trainer.fit(system, datamodule=dm)
    path = tmp_path / "simpnet.ckpt"
    trainer.save_checkpoint(path)
    # The registry finds the kind; no straight-line shortcut, so BKPIECE1 plans every problem with the sampler.
    planner = load_policy(path, direct=False, rollout_steps=5)
    assert planner.name == "simpnet"
    problems = problems_from_dataset(open_dataset(tiny[0]), "val", 2)
    result = evaluate(planner, problems)
    records = result["records"]
    assert all(r["success"]["2cm"] for r in records), [r.get("termination") for r in records]
    assert all(not r["collision"] for r in records) and planner.drawn["learned"] > 0, planner.drawn
