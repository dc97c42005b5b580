"""What a sweep worker keeps across its runs: the loaded checkpoint (by path and content) and
the link hulls (by URDF and model). Each run still gets its own wrapper and buffers."""

import shutil

import pytest

from tamedpuma.puma import primitive
from tamedpuma.puma.store import shipped_path
from tamedpuma.robot.ground import link_hulls
from tamedpuma.robot.kinematics import Kinematics


def test_a_checkpoint_is_loaded_once_per_content_and_wrapped_afresh(tmp_path):
    path = tmp_path / "puma.pt"
    shutil.copyfile(shipped_path("tomato", 2), path)
    primitive._LOADED.clear()
    a, b = primitive.load_primitive(path), primitive.load_primitive(path)
    assert a is not b and a.fast is not b.fast  # its own buffers and caches
    assert a.net is b.net and len(primitive._LOADED) == 1
    shutil.copyfile(shipped_path("pouring", 2), path)
    c = primitive.load_primitive(path)
    assert c.net is not a.net and len(primitive._LOADED) == 2


def test_the_link_hulls_are_built_once_per_model_and_read_only(robot_spec):
    kin = Kinematics(robot_spec)
    first, again = link_hulls(kin), link_hulls(Kinematics(robot_spec))
    assert first is again
    with pytest.raises(ValueError):
        first.vertices[0][0, 0] = 1.0
    other = link_hulls(Kinematics(robot_spec.controller_body()))
    if robot_spec.controller_body().spheres != robot_spec.spheres:  # other frames: its own
        assert other is not first


def test_the_schema_node_is_built_once_and_every_typing_starts_from_its_defaults():
    import dataclasses

    from omegaconf import OmegaConf

    from tamedpuma.app import schema
    from tamedpuma.errors import ConfigError

    method = schema.METHODS["fpm"]
    fresh = dataclasses.asdict(schema.typed(method, {"name": "fpm"}))
    node = schema._schema_node(method)
    before = OmegaConf.to_yaml(node)
    assert schema.typed(method, {"name": "fpm", "label": "mine"}).label == "mine"
    with pytest.raises(ConfigError):
        schema.typed(method, {"name": "fpm", "no_such_key": 1})
    assert schema._schema_node(method) is node and OmegaConf.to_yaml(node) == before
    assert dataclasses.asdict(schema.typed(method, {"name": "fpm"})) == fresh
    built = OmegaConf.structured(method)  # the node as a fresh build makes it
    schema._writable(built)
    assert OmegaConf.to_yaml(built) == before
