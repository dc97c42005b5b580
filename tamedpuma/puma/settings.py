"""PUMA's settings: the network's widths, the optimisation and the evaluation (numpy-free,
torch-free frozen dataclasses; their defaults are the config defaults, see ``app/schema.py``).

Each checks its ranges on construction and raises :class:`~tamedpuma.errors.ConfigError` naming
the key (``puma.train.iterations must be ...``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from tamedpuma.errors import ConfigError


def _check(obj, where: str, positive=(), nonneg=(), fraction=()) -> None:
    """Raise ConfigError for the first field of ``obj`` outside its range."""
    names = {f.name for f in fields(obj)}
    for group, rule, ok in ((positive, "> 0", lambda v: v > 0), (nonneg, ">= 0", lambda v: v >= 0),
                            (fraction, "in [0, 1]", lambda v: 0 <= v <= 1)):
        for name in group:
            assert name in names, name
            value = getattr(obj, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or \
                    not math.isfinite(value) or not ok(value):
                raise ConfigError(f"{where}.{name} must be a finite number {rule}, got {value!r}")


@dataclass(frozen=True)
class NetConfig:
    """Widths of the network: hidden ``width``, latent ``latent_dim``; ``out_quantile``: the
    quantile over the demonstrations of each one's peak |acceleration| (first order:
    |velocity|) that scales the output (1: the largest, 0.5: a typical demonstration's)."""

    width: int = 128
    latent_dim: int = 64
    pin_goal: bool = True
    skip: float = 1.0
    out_quantile: float = 1.0

    def __post_init__(self):
        _check(self, "puma.network", positive=("width", "latent_dim", "out_quantile"),
               nonneg=("skip",), fraction=("out_quantile",))


@dataclass(frozen=True)
class TrainConfig:
    """Optimisation settings (see ``conf/puma/default.yaml`` for meanings and units)."""

    iterations: int = 3000
    lr: float = 2e-3
    batch_windows: int = 48
    window: int = 25
    window_start: int = 0
    window_ramp: float = 0.5
    stability_batch: int = 64
    stability_horizon: int = 10
    stability_weight: float = 1.0
    stability_weight_end: float = 0.0
    stability_ramp_from: float = 0.5
    margin: float = 1e-6
    decay_rate: float = 0.0
    near_goal_fraction: float = 0.0
    persist: float = 0.95
    fresh_starts: int = 0
    select_every: int = 0
    select_from: float = 0.5
    val_starts: int = 300
    val_confirm: int = 0
    val_horizon: float = 0.0
    stop_dtw: float = 0.0
    keep_dtw: float = 0.0
    stop_compat: float = 0.0
    stop_spread: float = 0.0
    stop_gate: float = 0.0
    patience: int = 0
    min_delta: float = 0.03
    plateau_smooth: int = 1
    anneal: int = 0
    strict: bool = False
    squared_hinge: bool = False
    compat_weight: float = 0.1
    compat_eps: float = 0.01
    compat_eps_rel: float = 0.0
    compat_uniform: int = 0
    compat_exclude: float = 0.02
    path_weight: float = 0.0
    path_windows: int = 0
    sample_pad: float = 0.0
    boundary_weight: float = 0.0
    vel_weight: float = 0.1
    pos_weight: float = 1.0
    grad_clip: float = 1.0
    ema: float = 0.0
    threads: int = 1
    compile: bool = False
    log_every: int = 25

    def __post_init__(self):
        _check(self, "puma.train",
               positive=("iterations", "lr", "batch_windows", "window", "stability_horizon",
                         "compat_eps", "threads", "log_every", "plateau_smooth"),
               nonneg=("stability_batch", "stability_weight", "stability_weight_end", "margin",
                       "decay_rate", "fresh_starts",
                       "val_starts", "val_confirm", "val_horizon", "stop_dtw", "keep_dtw",
                       "stop_spread", "stop_gate", "window_start", "patience", "min_delta",
                       "anneal",
                       "select_every", "compat_weight", "compat_uniform", "compat_exclude",
                       "compat_eps_rel",
                       "path_weight", "path_windows",
                       "sample_pad",
                       "boundary_weight", "vel_weight", "pos_weight", "grad_clip"),
               fraction=("persist", "window_ramp", "near_goal_fraction", "select_from",
                         "stop_compat", "stability_ramp_from"))
        if not 0 <= self.ema < 1:
            raise ConfigError(f"puma.train.ema must be in [0, 1), got {self.ema!r}")
        if self.iterations > 1_000_000:
            raise ConfigError(f"puma.train.iterations must be at most 1000000 (time limit), "
                              f"got {self.iterations}")


@dataclass(frozen=True)
class EvalConfig:
    """Evaluation settings: starts, horizon [s], tolerances [unit, rad], compatibility samples,
    and the gates a trained model must pass (:mod:`tamedpuma.puma.gates`): mean DTW at most
    ``gate_spread`` × the demonstrations' own spread, each demonstration's DTW at most
    ``gate_worst`` × its distance to the nearest other one (never below ``gate_extent`` × its
    largest distance from the goal nor ``gate_floor`` × ``pos_tol``), at least
    ``gate_converged`` of the random starts converged and ``gate_compat`` of the states
    ψ-compatible (0 turns a gate off)."""

    random_starts: int = 1000
    horizon: float = 40.0
    pos_tol: float = 0.01
    ang_tol: float = 0.05
    compat_samples: int = 2000
    compat_min_dist: float = 0.02
    seed: int = 12345
    chunk: int = 1000
    gate_spread: float = 0.25
    gate_worst: float = 0.4
    gate_extent: float = 0.05
    gate_floor: float = 0.5
    gate_converged: float = 1.0
    gate_compat: float = 0.995

    def __post_init__(self):
        _check(self, "puma.eval", positive=("random_starts", "horizon", "pos_tol", "ang_tol",
                                            "compat_samples", "chunk"),
               nonneg=("compat_min_dist", "seed", "gate_spread", "gate_worst", "gate_extent",
                       "gate_floor"),
               fraction=("gate_converged", "gate_compat"))
