"""Named losses (conf/loss/, issue 18 item 6): `loss=paper` pins the paper's values, and each ablation of
`sweep=loss_terms` changes exactly the one term its name says, so the sweep measures one change at a time."""

from __future__ import annotations

import pytest
from omegaconf import OmegaConf

from samp.paths import conf_dir
from samp.policy.losses import LossConfig
from samp.train import compose_train_config

# The paper's values (Section III-C and its hyperparameter table; docs/design.md section 4), written out here as
# the oracle.
PAPER = {"match": 1.0, "collision": 20.0, "config": 1.0, "d_margin": 0.09, "d_target": 0.015, "tau": 1.0,
         "margin": "fixed"}
ABLATIONS = {"no_match": ("match", 0.0), "no_collision": ("collision", 0.0), "no_config": ("config", 0.0),
             "collision_x3": ("collision", 60.0), "tau_3cm": ("tau", 0.03), "tau_1cm": ("tau", 0.01)}


def _loss(name: str, experiment: str = "samp_cpu") -> dict:
    cfg = compose_train_config([f"experiment={experiment}", f"loss={name}"])
    assert cfg.loss == name
    return OmegaConf.to_container(cfg.system.loss)


@pytest.mark.parametrize("experiment", ["samp_cpu", "samp_n100", "quickstart"])
def test_paper_loss_is_the_papers_values_and_a_valid_loss_config(experiment):
    values = _loss("paper", experiment)
    assert values == PAPER
    assert LossConfig(**values) == LossConfig(**PAPER)


@pytest.mark.parametrize("name", sorted(ABLATIONS))
def test_each_ablation_changes_only_its_own_term(name):
    key, value = ABLATIONS[name]
    changed = _loss(name)
    LossConfig(**changed)  # a valid loss
    assert {k: v for k, v in changed.items() if PAPER[k] != v} == {key: value}


def test_the_sweep_measures_every_named_loss():
    sweep = OmegaConf.load(conf_dir() / "sweep" / "loss_terms.yaml")
    members = str(sweep.hydra.sweeper.params.loss).split(",")
    assert sorted(members) == sorted(p.stem for p in (conf_dir() / "loss").glob("*.yaml"))
    assert sorted(members) == sorted([*ABLATIONS, "paper"])
