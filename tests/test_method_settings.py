"""How many settings FPM and CPM have of their own (beyond PUMA's, which method=puma has too,
and the fabric gains): the count a reader must understand. It may only fall: a new setting
replaces one, or the budget here is raised in the same change with its ablation row
(docs/method.md)."""

from __future__ import annotations

import dataclasses

import pytest

from tamedpuma.app import schema

#: the current counts; docs/method.md lists each addition behind them
BUDGET = {"FpmMethod": 8, "CpmMethod": 11}


def leaves(cls, prefix: str = "") -> list[str]:
    """Dotted names of every scalar setting of a settings dataclass (nested ones flattened)."""
    out = []
    for f in dataclasses.fields(cls):
        default = (f.default_factory() if f.default_factory is not dataclasses.MISSING
                   else f.default)
        if dataclasses.is_dataclass(default):
            out += leaves(type(default), f"{prefix}{f.name}.")
        else:
            out.append(prefix + f.name)
    return out


def own_settings(cls) -> list[str]:
    puma = set(leaves(schema.PumaMethod))
    return [k for k in leaves(cls) if k not in puma and not k.startswith("fabric.")]


def test_leaves_flatten_nested_settings():
    names = leaves(schema.FpmMethod)
    assert "forcing.stall_pull" in names and "control_rate.barrier_step" in names
    assert "fabric.obstacle.energy_gain" in names and "forcing" not in names


@pytest.mark.parametrize("name", sorted(BUDGET))
def test_the_methods_own_settings_do_not_grow(name):
    own = own_settings(getattr(schema, name))
    assert len(own) <= BUDGET[name], own
    assert not any(k.startswith(("checkpoint", "pinv_", "null_space")) for k in own)


@pytest.mark.parametrize("name", sorted(schema.METHODS))
def test_each_method_takes_its_own_frozen_settings(name, kinematics):
    """One definition per setting: the schema's method class is the method's own settings
    dataclass plus ``name`` and ``label``; ``make`` takes that frozen dataclass, never a
    plain mapping."""
    from tamedpuma import methods

    settings = methods.settings_type(name)
    assert dataclasses.is_dataclass(settings) and settings.__dataclass_params__.frozen
    own = [f.name for f in dataclasses.fields(settings)]
    assert [f.name for f in dataclasses.fields(schema.METHODS[name])] == ["name", "label", *own]
    with pytest.raises(TypeError, match=settings.__qualname__):
        methods.make(name, {"name": name}, kinematics)


def test_the_sweep_hands_the_typed_settings_down(kinematics):
    """``method_settings`` of a composed run config is the method's frozen settings with the
    YAML's values (cpm_literal's constant damping) and the robot's "elbow up" link on the
    Panda (sweep.build replaces the method's iiwa link)."""
    from tamedpuma.app.compose import compose
    from tamedpuma.app.sweep import with_robot_null_space
    from tamedpuma.methods.cpm import CpmSettings

    run = schema.run_config(compose("sweep", ["method=cpm_literal", "robot=panda"]))
    settings = schema.method_settings(run.method)
    assert type(settings) is CpmSettings and settings.damping == "constant"
    assert settings.null_space.link == "lbr_iiwa_link_3"
    panda = with_robot_null_space(settings, run.robot.null_space)
    assert panda.null_space.link == "panda_link4" and panda.null_space.stiffness == 1.0


def differences(composed, default, prefix: str = "") -> list[str]:
    """Dotted names of the fields where two settings dataclasses differ (nested ones
    recursed), each with both values: ``"key: composed != default"``."""
    out = []
    for f in dataclasses.fields(default):
        a, b = getattr(composed, f.name), getattr(default, f.name)
        if dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b) and type(a) is type(b):
            out += differences(a, b, f"{prefix}{f.name}.")
        elif a != b:
            out.append(f"{prefix}{f.name}: {a!r} != {b!r}")
    return out


def method_options() -> list[str]:
    """The ``conf/method`` options whose name is a registered method (the others, e.g.
    ``fpm_literal``, are configured variants of one)."""
    from tamedpuma import methods
    from tamedpuma.app.config import group_options

    return [name for name in group_options("method") if name in methods.available()]


def test_every_method_of_the_package_has_its_config():
    from tamedpuma import methods

    assert set(methods.builtin()) <= set(method_options())


@pytest.mark.parametrize("name", method_options())
def test_the_settings_defaults_are_what_the_method_config_composes(name):
    """One set of defaults: ``method=<name>`` composes to the method's ``SETTINGS()`` field by
    field (``task``, the task config's name interpolated, aside), so a value changed in the
    dataclass or in ``conf/method/<name>.yaml`` alone fails here. The variants
    (``fpm_literal``, ``cpm_literal``, ``cpm_original``) override these defaults."""
    from tamedpuma import methods
    from tamedpuma.app.compose import compose_typed

    composed = schema.method_settings(compose_typed("sweep", [f"method={name}"]).method)
    default = methods.settings_type(name)()
    assert type(composed) is type(default)
    if any(f.name == "task" for f in dataclasses.fields(default)):
        composed = dataclasses.replace(composed, task=default.task)
    assert differences(composed, default) == []
    assert composed == default
