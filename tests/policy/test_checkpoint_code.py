"""A checkpoint or robot SDF artifact is data: what it describes may name no code to run (docs/design.md
section 7). Loading is `weights_only`, but two descriptions inside the file were turned into calls: the
optimizer node of a policy's hyperparameters (Hydra instantiates nested `_target_` nodes) and the robot SDF
network's class. Each crafted description below would write a marker file if it were called."""

from __future__ import annotations

import pytest

from samp.policy.base import _partial
from samp.robot_sdf.artifact import build_net


def _writes(marker) -> dict:
    return {"_target_": "builtins.exec", "_args_": [f"open({str(marker)!r}, 'w').write('ran')"]}


def test_an_optimizer_node_that_nests_code_is_refused(tmp_path):
    marker = tmp_path / "ran"
    node = {"_target_": "torch.optim.AdamW", "lr": 1e-3, "weight_decay": _writes(marker)}
    with pytest.raises(ValueError, match="may not name code"):
        _partial(node, "optimizer")
    assert not marker.exists(), "the nested target was called"


def test_an_optimizer_node_that_names_other_code_is_refused(tmp_path):
    marker = tmp_path / "ran"
    with pytest.raises(ValueError, match="not a torch optimizer"):
        _partial({**_writes(marker), "_partial_": False}, "optimizer")
    assert not marker.exists()


def test_torch_optimizers_and_schedulers_still_build():
    import torch

    param = torch.nn.Parameter(torch.zeros(2))
    opt = _partial({"_target_": "torch.optim.AdamW", "lr": 1e-3, "betas": [0.9, 0.99]}, "optimizer")([param])
    sched = _partial({"_target_": "torch.optim.lr_scheduler.CosineAnnealingWarmRestarts", "T_0": 5}, "scheduler")(opt)
    assert isinstance(opt, torch.optim.AdamW) and opt.defaults["lr"] == 1e-3 and sched.T_0 == 5


@pytest.mark.parametrize("target", ["builtins.exec", "os.system", "samp.robot_sdf.artifact.build_net"])
def test_a_robot_sdf_network_that_names_other_code_is_refused(tmp_path, target):
    marker = tmp_path / "ran"
    with pytest.raises(ValueError, match="refused"):
        build_net({"target": target, "kwargs": {"source": f"open({str(marker)!r}, 'w')"}})
    assert not marker.exists()


def test_a_robot_sdf_network_with_nested_code_is_refused(tmp_path):
    marker = tmp_path / "ran"
    with pytest.raises(ValueError, match="plain values"):
        build_net({"target": "samp.robot_sdf.model.UnifiedHashSDF", "kwargs": {"num_links": _writes(marker)}})
    assert not marker.exists()


def test_the_robot_sdf_networks_samp_writes_still_build(robots, small_robot_sdf):
    artifact = small_robot_sdf(robots["panda"])
    net = build_net(artifact["info"]["net"])
    net.load_state_dict(artifact["state_dict"])
