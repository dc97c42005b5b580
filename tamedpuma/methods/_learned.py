"""Shared by the methods driven by a trained PUMA primitive (puma, fpm, cpm): loading the
checkpoint named in the method config (or the best model at hand) and choosing the task adapter."""

from __future__ import annotations

from pathlib import Path

from tamedpuma.errors import CheckpointError, ConfigError
from tamedpuma.methods._policy import NullSpaceObjective, PlanarTask, PoseTask


def model_path(settings, order: int) -> Path:
    """The checkpoint a method's settings name, or, with ``checkpoint`` null, the best model at
    hand for ``settings.task`` (cache, user-trained, shipped):
    :func:`tamedpuma.puma.store.resolve`, the one place a model is found. A plugin's settings
    without ``task``, ``checkpoint`` or ``model`` count as null there."""
    from tamedpuma.puma import store

    checkpoint = getattr(settings, "checkpoint", None) or None
    task = getattr(settings, "task", None)
    if not checkpoint and not task:
        raise ConfigError("method.checkpoint and method.task are not set")
    model = "auto" if checkpoint else str(settings.model)  # an explicit checkpoint is used as is
    return store.resolve(str(task or "<task>"), order, checkpoint, model).path


def load_task(settings):
    """Load the checkpoint ``settings`` name and wrap it in the task adapter of its kind."""
    from tamedpuma.puma.primitive import PosePrimitive, load_primitive

    primitive = load_primitive(model_path(settings, order=2))
    if isinstance(primitive, PosePrimitive):
        return PoseTask(primitive)
    if primitive.spec.order != 2:
        raise CheckpointError(f"{settings.checkpoint} is a first-order model; this method needs "
                              "a second-order PUMA")
    return PlanarTask(primitive, dims=primitive.spec.n_pos)


def null_objective(settings) -> NullSpaceObjective | None:
    """The optional null-space objective of
    :class:`~tamedpuma.methods._settings.NullSpaceSettings` (None if absent or without a link)."""
    if settings is None or not settings.link:
        return None
    target = tuple(float(v) for v in settings.target)
    return NullSpaceObjective(str(settings.link), target, float(settings.stiffness),
                              float(settings.damping))
