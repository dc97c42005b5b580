"""Path difference between two end-effector paths (experiments.md, "Metrics").

``d(a, b) = (1/P) Σ_p ‖a(s_p) − b(s_p)‖₂`` [m], both paths resampled at P points equally spaced in
arc length (so the speed along the path does not matter, only its shape).
"""

from __future__ import annotations

import numpy as np


def resample_by_arc_length(path: np.ndarray, points: int) -> np.ndarray:
    """(T, d) path -> (points, d), equally spaced in arc length (linear interpolation)."""
    path = np.asarray(path, dtype=float)
    if len(path) == 1:
        return np.repeat(path, points, axis=0)
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    if s[-1] == 0:
        return np.repeat(path[:1], points, axis=0)
    targets = np.linspace(0.0, s[-1], points)
    return np.stack([np.interp(targets, s, path[:, k]) for k in range(path.shape[1])], axis=1)


def path_difference(a: np.ndarray, b: np.ndarray, points: int = 200) -> float:
    """Mean distance [m] between paths a and b resampled by arc length to ``points`` points."""
    ra, rb = resample_by_arc_length(a, points), resample_by_arc_length(b, points)
    return float(np.mean(np.linalg.norm(ra - rb, axis=1)))
