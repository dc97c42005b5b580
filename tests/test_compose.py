"""The one place configs are composed (tamedpuma/app/compose.py): Hydra's state before and after,
the plain and typed results, and Hydra's errors as one line."""

from __future__ import annotations

import pytest
from hydra.core.global_hydra import GlobalHydra

from tamedpuma.app.compose import compose, compose_dict, session
from tamedpuma.errors import ConfigError


def test_a_composition_leaves_no_hydra_behind_and_a_session_holds_it_for_many():
    GlobalHydra.instance().clear()
    cfg = compose("sweep", ["method=cpm"])
    assert cfg.method.name == "cpm" and "hydra" not in cfg
    assert not GlobalHydra.instance().is_initialized()
    with session():
        a = compose("sweep", ["method=fpm"])
        assert GlobalHydra.instance().is_initialized()  # reused, not torn down by compose
        b = compose("sweep", ["method=fabrics"], hydra_config=True)
    assert not GlobalHydra.instance().is_initialized()
    assert a.method.name == "fpm" and b.method.name == "fabrics" and "hydra" in b


def test_the_plain_configs_are_resolved_and_the_typed_ones_complete():
    run = compose_dict("sweep", ["task=pouring"])
    assert isinstance(run, dict) and run["task"]["name"] == "pouring"
    assert run["scenario"]["goal"]["position"] == run["task"]["goal_position"]  # resolved
    train = compose_dict("train", ["task=tomato", "puma=tiny"])
    assert train["task"]["name"] == "tomato" and "iterations" in train["puma"]["train"]
    assert not GlobalHydra.instance().is_initialized()


@pytest.mark.parametrize("config,override,match", [
    ("sweep", "scenario=nowhere", r"Available options in 'scenario':.*tomato/00"),
    ("train", "task=nothing", r"Available options in 'task':.*pouring"),
    ("sweep", "seed=abc", r"Error merging override seed=abc: .*"),
])
def test_hydra_errors_become_one_line_config_errors(config, override, match):
    with pytest.raises(ConfigError, match=match) as err:
        compose_dict(config, [override])
    assert "\n" not in str(err.value) and "HYDRA_FULL_ERROR" not in str(err.value)
    assert not GlobalHydra.instance().is_initialized()
