"""How closely can a first-order field follow the demonstrations at all?

A first-order primitive commands a velocity from the position alone, ``ẋ = f(x)``. Where two
demonstrations pass within millimetres of each other with different velocities (a crossing, or
one route travelled at two speeds), no such field follows both: the data, not the learner, sets
how closely it can imitate them. A second-order primitive (``ẍ = f(x, ẋ)``) is not bound by
this: its state holds the velocity.

The measure is a field that follows the data as closely as a smooth field can at a length scale
h: the kernel regression of the demonstrations' own velocities,

    v_h(x) = Σ_j w_j v_j / Σ_j w_j,   w_j = exp(−‖x − p_j‖² / 2h²),

over every sample p_j of every demonstration (positions relative to each one's goal, the
appended rest samples included) with its forward velocity ``v_j = (p_{j+1} − p_j)/Δt`` [unit/s]
(0 on the last sample), rolled out by Euler steps of Δt from each demonstration's start for the
demonstration's length, and compared with it as the evaluation compares a model's rollout (DTW
per point, :func:`~tamedpuma.puma.evaluation.dtw_per_point_batch`). Where the demonstrations
never come within a few h of each other with other velocities, v_h reproduces them to a small
fraction of h; where they do, it averages their velocities there and its rollout takes another
route. The gates use h = ``gate_floor`` × ``pos_tol`` (half the convergence tolerance, 5 mm by
default): a first-order model that misses a demonstration which v_h misses too is told that the
data asks for a second-order model (:mod:`tamedpuma.puma.gates`).
"""

from __future__ import annotations

import numpy as np

from .data import Demonstrations
from .evaluation import dtw_per_point_batch


def samples(demos: Demonstrations) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, n) [unit], forward velocities (N, n) [unit/s]) of every sample of every
    demonstration (the appended rest samples included; the last sample of each at rest)."""
    pos, vel = [], []
    for p in demos.pos:
        v = np.zeros_like(p)
        v[:-1] = np.diff(p, axis=0) / demos.dt
        pos.append(p)
        vel.append(v)
    return np.concatenate(pos), np.concatenate(vel)


def rollouts(demos: Demonstrations, bandwidth: float) -> list[np.ndarray]:
    """The paths (len_i, n) [unit] of the kernel field v_h (h = ``bandwidth`` [unit]) from each
    demonstration's start, each as long as its demonstration (the rest samples excluded)."""
    if not bandwidth > 0:
        raise ValueError(f"bandwidth must be positive, got {bandwidth}")
    P, V = samples(demos)
    starts = [demos.trimmed(i)[0] for i in range(len(demos))]
    lengths = [len(p) for p in starts]
    x = np.stack([p[0] for p in starts]).astype(float)
    paths = np.empty((max(lengths), *x.shape))
    paths[0] = x
    inv = 0.5 / bandwidth**2
    sq = np.einsum("ij,ij->i", P, P)
    for k in range(1, len(paths)):
        d2 = np.einsum("ij,ij->i", x, x)[:, None] - 2.0 * x @ P.T + sq[None]
        w = np.exp(-inv * (d2 - d2.min(axis=1, keepdims=True)))  # the nearest sample's weight 1
        x = x + demos.dt * (w @ V) / w.sum(axis=1, keepdims=True)
        paths[k] = x
    return [paths[: n, i] for i, n in enumerate(lengths)]


def first_order_dtw(demos: Demonstrations, bandwidth: float) -> np.ndarray:
    """Per demonstration: DTW per point [unit] of the kernel field's rollout (:func:`rollouts`)
    against it; how closely a first-order field smooth at ``bandwidth`` [unit] can follow it."""
    refs = [demos.trimmed(i)[0] for i in range(len(demos))]
    return dtw_per_point_batch(rollouts(demos, bandwidth), refs)
