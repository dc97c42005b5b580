"""How many settings FPM and CPM have of their own (beyond PUMA's, which method=puma has too,
and the fabric gains): the count a reader must understand. It may only fall: a new setting
replaces one, or the budget here is raised in the same change with its ablation row
(docs/method.md)."""

from __future__ import annotations

import dataclasses

import pytest

from tamedpuma.app import schema

#: the current counts; docs/method.md lists each addition behind them
BUDGET = {"FpmMethod": 12, "CpmMethod": 16}


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
