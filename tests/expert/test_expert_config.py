"""Expert config loading and validation, planner names, the cuRobo backend refused (planned work)."""

from __future__ import annotations

import dataclasses

import pytest

from samp.expert import ExpertConfig, available_planners, load_expert_config, make_planner
from samp.expert.curobo import CuroboPlanner, curobo_available
from samp.scene import Scene


def test_default_yaml_matches_the_schema_defaults():
    cfg = load_expert_config()
    assert cfg == ExpertConfig(), ("conf/expert/default.yaml and samp/expert/config.py disagree: "
                                   f"{dataclasses.asdict(cfg)} vs {dataclasses.asdict(ExpertConfig())}")
    assert cfg.planner == "RRTConnect" and cfg.waypoints == 50


def test_overrides_and_mappings():
    cfg = load_expert_config(planner="AORRTC", time_limit=2.0)
    assert (cfg.planner, cfg.time_limit) == ("AORRTC", 2.0)
    cfg = load_expert_config({"attempts": 5, "ik": {"seeds": 8}})
    assert (cfg.attempts, cfg.ik.seeds, cfg.ik.iterations) == (5, 8, ExpertConfig().ik.iterations)
    assert load_expert_config(cfg) == cfg


def test_unknown_key_names_the_valid_ones():
    with pytest.raises(ValueError, match=r"timelimit.*Valid keys: .*time_limit"):
        load_expert_config({"timelimit": 3})
    with pytest.raises(ValueError, match="unknown expert config 'nope'"):
        load_expert_config("nope")


@pytest.mark.parametrize("override, message", [
    ({"attempts": 0}, "attempts"), ({"resolution": -0.1}, "resolution"), ({"check_margin": 0.5}, "check_margin"),
    ({"backend": "gpu"}, "backend"), ({"problems": {"start": "home"}}, "problems.start"),
])
def test_bad_values_are_refused(override, message):
    with pytest.raises(ValueError, match=message):
        load_expert_config(override)


def test_planners_exist_in_this_ompl():
    names = available_planners()
    for name in ("RRTConnect", "AORRTC", "RRTstar"):
        assert name in names, f"{name} missing from {names}"


def test_unknown_planner_lists_the_available_ones(robots):
    with pytest.raises(ValueError, match=r"unknown planner 'RRTmagic'; available planners: RRTConnect, AORRTC, RRTstar"):
        make_planner(robots["panda"], Scene("empty"), load_expert_config(planner="RRTmagic"))


def test_curobo_backend_is_refused_as_not_implemented(robots):
    """Not offered: selecting it (a config, an override, a dataset spec) is a clear error, whatever the machine."""
    with pytest.raises(ValueError, match="backend 'curobo' is not implemented.*planned work.*use backend: ompl"):
        load_expert_config(backend="curobo")
    with pytest.raises(ValueError, match="backend 'curobo' is not implemented"):
        make_planner(robots["panda"], Scene("empty"), {"backend": "curobo"})
    with pytest.raises(NotImplementedError, match="planned work"):
        CuroboPlanner(robots["panda"], Scene("empty"), load_expert_config())
    ok, why = curobo_available()
    assert ok or "cuRobo" in why
