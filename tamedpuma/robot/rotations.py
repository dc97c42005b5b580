"""Rotations, numpy only: quaternions (x, y, z, w) to and from matrices, the SO(3) log and exp
maps, the angle between orientations, URDF roll-pitch-yaw.

Shared by the IK, the fabrics' orientation attractor, the methods, the metrics, the body model and
PUMA's data preparation (one implementation; PUMA's differentiable torch versions are in
:mod:`tamedpuma.puma.manifold`).
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


def exp_so3(omega: np.ndarray) -> np.ndarray:
    """Rotation matrix exp([ω]×) of a rotation vector ω [rad] (Rodrigues)."""
    angle = float(np.linalg.norm(omega))
    k = np.array([[0.0, -omega[2], omega[1]], [omega[2], 0.0, -omega[0]],
                  [-omega[1], omega[0], 0.0]])
    if angle < 1e-9:
        return np.eye(3) + k
    return (np.eye(3) + np.sin(angle) / angle * k
            + (1.0 - np.cos(angle)) / angle**2 * k @ k)


def orientation_error(quat: np.ndarray, goal_quat: np.ndarray) -> np.ndarray:
    """Angle [rad] of the rotation between unit quaternions (…, 4) and (…, 4), in [0, π]."""
    dot = np.abs(np.sum(np.asarray(quat) * np.asarray(goal_quat), axis=-1))
    return 2.0 * np.arccos(np.clip(dot, 0.0, 1.0))


def rpy_to_matrix(rpy) -> np.ndarray:
    """Rotation matrix (3, 3) of URDF roll-pitch-yaw angles [rad]: R = R_z(y) R_y(p) R_x(r)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) → unit quaternions (..., 4) (x, y, z, w), w ≥ 0.

    Shepperd's method: pick the largest of (w, x, y, z) to divide by, for accuracy.
    """
    m = np.asarray(m, float)
    shape = m.shape[:-2]
    m = m.reshape(-1, 3, 3)
    tr = np.trace(m, axis1=1, axis2=2)
    diag = np.stack((m[:, 0, 0], m[:, 1, 1], m[:, 2, 2], tr), axis=1)
    k = np.argmax(diag, axis=1)
    q = np.empty((len(m), 4))
    for i in range(4):
        sel = k == i
        r = m[sel]
        if i == 3:
            s = 2.0 * np.sqrt(1.0 + tr[sel])
            q[sel] = np.stack((r[:, 2, 1] - r[:, 1, 2], r[:, 0, 2] - r[:, 2, 0],
                               r[:, 1, 0] - r[:, 0, 1], 0.25 * s * s), axis=1) / s[:, None]
        else:
            j, l = (i + 1) % 3, (i + 2) % 3
            s = 2.0 * np.sqrt(1.0 + r[:, i, i] - r[:, j, j] - r[:, l, l])
            out = np.empty((len(r), 4))
            out[:, i] = 0.25 * s
            out[:, j] = (r[:, j, i] + r[:, i, j]) / s
            out[:, l] = (r[:, l, i] + r[:, i, l]) / s
            out[:, 3] = (r[:, l, j] - r[:, j, l]) / s
            q[sel] = out
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    q = np.where(q[:, 3:] < 0, -q, q)
    return q.reshape(*shape, 4)


def quats_to_matrices(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) (x, y, z, w) → rotation matrices (..., 3, 3)."""
    q = np.asarray(q, float)
    x, y, z, w = np.moveaxis(q / np.linalg.norm(q, axis=-1, keepdims=True), -1, 0)
    return np.stack((
        np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)), -1),
        np.stack((2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)), -1),
        np.stack((2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)), -1),
    ), -2)


def continuous_quats(q: np.ndarray) -> np.ndarray:
    """Flip signs along a (N, 4) sequence so consecutive quaternions have a positive dot product."""
    q = np.array(q, float)
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0:
            q[i] = -q[i]
    return q
