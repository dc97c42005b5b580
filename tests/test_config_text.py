"""config_text.to_yaml writes OmegaConf.to_yaml's text, byte for byte."""

from __future__ import annotations

import pytest
import yaml
from omegaconf import OmegaConf

from tamedpuma.app import config_text
from tamedpuma.app.compose import compose, session

#: a job of each shipped experiment (its own overrides, a method that loads nothing)
_JOBS = [["+experiment=table1", "method=fabrics", "case=tomato_03", "without_obstacles=true"],
         ["+experiment=random", "method=fabrics", "task=pouring", "scenario.random_seed=2051"],
         ["+experiment=scaling", "method=fabrics"],
         ["+experiment=disturbance", "method=fabrics"],
         ["+experiment=ablation", "method=fabrics"],
         ["method=modulation_ik", "task=pouring", "scenario=pouring/07"],
         ["method=cpm", "recorder=mcap", "seed=3"]]


@pytest.mark.skipif(not yaml.__with_libyaml__, reason="PyYAML without libyaml: the same path")
def test_every_shipped_experiments_config_and_hydra_node_dump_as_omegaconf_dumps_them():
    with session():
        for overrides in _JOBS:
            cfg = compose("sweep", overrides, hydra_config=True)
            for node in (cfg, cfg.hydra, cfg.hydra.overrides.task):
                assert config_text.to_yaml(node) == OmegaConf.to_yaml(node)
            plain = OmegaConf.masked_copy(cfg, [k for k in cfg if k != "hydra"])
            assert (config_text.to_yaml(plain, resolve=True)
                    == OmegaConf.to_yaml(plain, resolve=True))


def test_strings_that_read_back_as_other_types_long_lines_and_unicode_dump_alike():
    cfg = OmegaConf.create({
        "quoted": ["yes", "no", "on", "off", "true", "1", "1.5", "1e3", "-0", ".inf", "nan"],
        "plain": ["null", "~", "", " lead", "trail ", "a: b", "#x", "- y", "é ü 中", "'q'", '"d"'],
        "long": "word " * 40, "lines": "one\ntwo\n\nthree\n", "tab": "a\tb",
        "nested": {"x": [1, 2.5, None, True, {"y": "${nested.x}"}], "empty": {}, "none": []},
        "float": [1e-300, 1.0e20, -0.0, 3.141592653589793], "int": [0, -7, 2**70]})
    assert config_text.to_yaml(cfg) == OmegaConf.to_yaml(cfg)
    assert OmegaConf.create(config_text.to_yaml(cfg)) == cfg


def test_save_config_writes_the_text_into_a_new_folder(tmp_path):
    cfg = OmegaConf.create({"a": {"b": [1, "2"]}})
    config_text.save_config(cfg, "config.yaml", tmp_path / ".hydra")
    assert (tmp_path / ".hydra" / "config.yaml").read_text() == OmegaConf.to_yaml(cfg)
