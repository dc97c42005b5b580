"""Rotations, numpy only: quaternions (x, y, z, w) to matrices and the SO(3) log map.

Shared by the IK, the fabrics' orientation attractor and the methods (one implementation).
"""

from __future__ import annotations

import numpy as np


def quat_to_matrix(quat: np.ndarray) -> np.ndarray:
    """Rotation matrix (3, 3) of a quaternion (x, y, z, w) (normalised first)."""
    x, y, z, w = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rotation_error(rot: np.ndarray, goal_rot: np.ndarray) -> np.ndarray:
    """World-frame rotation vector ω [rad] with exp([ω]×) R = R_g (the log map of R_g Rᵀ)."""
    rel = goal_rot @ rot.T
    cos = np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0)
    angle = np.arccos(cos)
    axis = np.array([rel[2, 1] - rel[1, 2], rel[0, 2] - rel[2, 0], rel[1, 0] - rel[0, 1]])
    if angle < 1e-9:
        return 0.5 * axis
    if np.pi - angle < 1e-6:  # near π: axis from the symmetric part
        sym = (rel + np.eye(3)) / 2.0
        axis = sym[:, int(np.argmax(np.diag(sym)))]
        return angle * axis / np.linalg.norm(axis)
    return angle * axis / (2.0 * np.sin(angle))
