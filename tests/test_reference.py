"""The reference motion of clutter.keep_clear=path (tamedpuma/app/reference.py)."""

from __future__ import annotations

import pytest
from hydra import compose, initialize_config_dir

from tamedpuma.app.config import CONF_DIR
from tamedpuma.app.reference import reference_config, reference_motion
from tamedpuma.app.sweep import build
from tamedpuma.errors import ScenarioError


def _cfg(*overrides):
    with initialize_config_dir(str(CONF_DIR), version_base="1.3"):
        return compose("sweep", overrides=["method=fabrics", "clutter.total=50",
                                           "clutter.keep_clear=path", "recorder=mcap",
                                           "scenario.max_steps=7", *overrides])


def test_reference_config_is_the_run_with_the_reference_method_and_no_clutter():
    cfg = _cfg("clutter.reference=joint_attractor", "clutter.reference_max_steps=30")
    ref = reference_config(cfg)
    assert ref.method.name == "joint_attractor" and cfg.method.name == "fabrics"
    assert ref.clutter.total is None and ref.clutter.count == 0
    assert ref.clutter.keep_clear == "start_goal"
    assert ref.scenario.max_steps == 30 and not ref.recorder.mcap and not ref.recorder.rerun
    assert ref.scenario.name == cfg.scenario.name and ref.seed == cfg.seed


def test_a_reference_that_does_not_succeed_is_a_one_line_error():
    cfg = _cfg("clutter.reference=joint_attractor", "clutter.reference_max_steps=3")
    with pytest.raises(ScenarioError, match=r"reference run \(joint_attractor on default, own "
                                            r"obstacles only\) did not succeed \[\w+\]") as err:
        reference_motion(cfg, build)
    assert "\n" not in str(err.value)
    with pytest.raises(ScenarioError, match="did not succeed"):
        build(cfg)  # the sweep's build asks for the reference when it adds clutter
