"""Shared by the methods driven by a trained PUMA primitive (puma, fpm, cpm): loading the
checkpoint named in the method config (or the best model at hand) and choosing the task adapter."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from tamedpuma.errors import CheckpointError, ConfigError
from tamedpuma.methods._policy import NullSpaceObjective, PlanarTask, PoseTask


def model_path(cfg: Mapping, order: int) -> Path:
    """The checkpoint a method config names, or, with ``checkpoint`` null, the best model at hand
    for ``cfg['task']`` (cache, user-trained, shipped): :func:`tamedpuma.puma.store.resolve`, the
    one place a model is found."""
    from tamedpuma.puma import store

    checkpoint = cfg.get("checkpoint") or None
    if not checkpoint and not cfg.get("task"):
        raise ConfigError("method.checkpoint and method.task are not set")
    model = "auto" if checkpoint else str(cfg["model"])  # an explicit checkpoint is used as is
    return store.resolve(str(cfg.get("task") or "<task>"), order, checkpoint, model).path


def load_task(cfg: Mapping):
    """Load ``cfg['checkpoint']`` and wrap it in the task adapter of its kind."""
    from tamedpuma.puma.primitive import PosePrimitive, load_primitive

    primitive = load_primitive(model_path(cfg, order=2))
    if isinstance(primitive, PosePrimitive):
        return PoseTask(primitive)
    if primitive.spec.order != 2:
        raise CheckpointError(f"{cfg['checkpoint']} is a first-order model; this method needs a "
                              "second-order PUMA")
    return PlanarTask(primitive, dims=primitive.spec.n_pos)


def null_objective(cfg: Mapping | None) -> NullSpaceObjective | None:
    """The optional null-space objective of a ``null_space`` config block (None if disabled)."""
    if not cfg or not cfg.get("link"):
        return None
    target = tuple(float(v) for v in cfg["target"])
    if len(target) != 3:
        raise ConfigError("null_space.target must be 3 numbers [m]")
    return NullSpaceObjective(str(cfg["link"]), target, float(cfg["stiffness"]),
                              float(cfg["damping"]))

