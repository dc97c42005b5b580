"""Shared by the methods driven by a trained PUMA primitive (puma, fpm, cpm): loading the
checkpoint named in the method config (or the best model at hand) and choosing the task adapter."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

from tamedpuma.errors import CheckpointError, ConfigError
from tamedpuma.methods._policy import NullSpaceObjective, PlanarTask, PoseTask


def resolve_checkpoint(path: str) -> Path:
    """The checkpoint file: absolute, else relative to the working directory, else to the
    repository root. A missing file is a :class:`CheckpointError` saying how to make one."""
    p = Path(path)
    repo = Path(__file__).resolve().parents[2]
    candidates = [p] if p.is_absolute() else [Path.cwd() / p, repo / p]
    for c in candidates:
        if c.is_file():
            return c
    task = p.parent.name or "<task>"
    raise CheckpointError(f"no PUMA checkpoint at {path}: train one with "
                          f"`python -m tamedpuma.train task={task}` (or set method.checkpoint)")


def model_path(cfg: Mapping, order: int) -> Path:
    """The checkpoint a method config names, or, with ``checkpoint`` null, the best model at hand
    for ``cfg['task']`` (cache, user-trained, shipped: :mod:`tamedpuma.puma.store`)."""
    if cfg.get("checkpoint"):
        return resolve_checkpoint(str(cfg["checkpoint"]))
    if not cfg.get("task"):
        raise ConfigError("method.checkpoint and method.task are not set")
    from tamedpuma.puma import store

    return store.resolve(str(cfg["task"]), order, None, str(cfg["model"])).path


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

