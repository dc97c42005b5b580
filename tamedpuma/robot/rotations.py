"""Rotations, numpy only: quaternions (x, y, z, w) to and from matrices, their product,
conjugate, one-quaternion exp and log, and relative rotation, the SO(3) log and exp maps,
cross-product matrices, the angle between orientations, URDF roll-pitch-yaw.

The only rotation module: shared by the IK, the fabrics' orientation attractor, the methods, the
metrics, the body model, the scenario generators and PUMA's data preparation and numpy networks.
PUMA's differentiable torch versions (and the numpy ``np_quat_exp``/``np_quat_log`` that run them)
are in :mod:`tamedpuma.puma.manifold`. :func:`rotation_entries` and :func:`relative_rotation` work
on Python floats (one state, no array overhead); every other function on arrays.
:func:`bullet_rotation_matrices` repeats Bullet's own operation order (the simulator's sphere
centres, to the last bit).
"""

from __future__ import annotations

import math

import numpy as np


def _skew_generators() -> np.ndarray:
    """E (3, 9) with ``skew(v).ravel() = v @ E`` for v (…, 3); row k is ``[e_k]×`` raveled."""
    E = np.zeros((3, 3, 3))
    E[0, 1, 2], E[0, 2, 1] = -1.0, 1.0
    E[1, 0, 2], E[1, 2, 0] = 1.0, -1.0
    E[2, 0, 1], E[2, 1, 0] = -1.0, 1.0
    return E.reshape(3, 9)


#: (3, 9): ``skew(v).ravel() = v @ SKEW_GENERATORS`` (the entries of ``[v]×`` are linear in v)
SKEW_GENERATORS = _skew_generators()


def skew(v):
    """Cross-product matrices ``[v]×`` (…, 3, 3) of v (…, 3), so that ``[v]× w = v × w``."""
    v = np.asarray(v, dtype=float)
    return (v @ SKEW_GENERATORS).reshape(v.shape[:-1] + (3, 3))


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product ``a ⊗ b`` of (..., 4) quaternions (x, y, z, w)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    ax, ay, az, aw = a[..., 0], a[..., 1], a[..., 2], a[..., 3]
    bx, by, bz, bw = b[..., 0], b[..., 1], b[..., 2], b[..., 3]
    return np.stack((aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw,
                     aw * bw - ax * bx - ay * by - az * bz), axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    """Conjugate ``(−x, −y, −z, w)`` of (..., 4) quaternions (the inverse of a unit quaternion)."""
    q = np.asarray(q, float)
    return np.concatenate((-q[..., :3], q[..., 3:]), axis=-1)


def relative_quat(quat, goal_quat) -> np.ndarray:
    """``ζ ⊗ ζ_g⁻¹`` of (..., 4) quaternions (x, y, z, w), both normalised first: the rotation
    from the goal's orientation to ζ, in the world frame."""
    q = np.asarray(quat, dtype=np.float64)
    g = np.asarray(goal_quat, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    g = g / np.linalg.norm(g, axis=-1, keepdims=True)
    g = g * np.array([-1.0, -1.0, -1.0, 1.0])
    return quat_mul(q, g)


def quat_exp(theta: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w) of one rotation vector θ [rad] (3,) (numpy, one state: the
    batched torch version is :func:`tamedpuma.puma.manifold.quat_exp`)."""
    angle = float(np.linalg.norm(theta))
    if angle < 1e-12:
        return np.array([0.5 * theta[0], 0.5 * theta[1], 0.5 * theta[2], 1.0])
    s = np.sin(0.5 * angle) / angle
    return np.array([s * theta[0], s * theta[1], s * theta[2], np.cos(0.5 * angle)])


def quat_log(q: np.ndarray) -> np.ndarray:
    """Rotation vector θ [rad] (3,) of a unit quaternion (x, y, z, w), the shorter way
    (|θ| ≤ π: q and −q give the same θ)."""
    v, w = (q[:3], q[3]) if q[3] >= 0.0 else (-q[:3], -q[3])
    n = float(np.linalg.norm(v))
    if n < 1e-12:
        return 2.0 * v
    return (2.0 * np.arctan2(n, w) / n) * v


def quat_angle(q: np.ndarray) -> np.ndarray:
    """Rotation angle [rad] in [0, π] of unit quaternions (..., 4): ``2 atan2(‖v‖, |w|)``."""
    q = np.asarray(q, float)
    return 2.0 * np.arctan2(np.linalg.norm(q[..., :3], axis=-1), np.abs(q[..., 3]))


def rotation_entries(x, y, z, w) -> list[float]:
    """Row-major entries of the rotation matrix of a unit quaternion (x, y, z, w), as floats
    (not normalised)."""
    return [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]


def _inv_norm(sq: float) -> float:
    """1/√sq; NaN for a zero (or NaN) quaternion, as numpy's 0/0 (no ZeroDivisionError)."""
    return 1.0 / math.sqrt(sq) if sq > 0.0 else math.nan


def relative_rotation(quat, goal_quat) -> list[float]:
    """Row-major entries of R(ζ ⊗ ζ_g⁻¹) (both normalised first), as :func:`relative_quat` then
    :func:`rotation_entries`, on Python floats (one state)."""
    ax, ay, az, aw = quat
    na = _inv_norm(ax * ax + ay * ay + az * az + aw * aw)
    ax, ay, az, aw = ax * na, ay * na, az * na, aw * na
    bx, by, bz, bw = goal_quat
    nb = _inv_norm(bx * bx + by * by + bz * bz + bw * bw)
    bx, by, bz, bw = -bx * nb, -by * nb, -bz * nb, bw * nb
    return rotation_entries(*_product(ax, ay, az, aw, bx, by, bz, bw))


def _product(ax, ay, az, aw, bx, by, bz, bw) -> tuple[float, float, float, float]:
    """The Hamilton product a ⊗ b of two quaternions (x, y, z, w) given as Python floats, in
    :func:`quat_mul`'s order of operations."""
    return (aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
            aw * bw - ax * bx - ay * by - az * bz)


def error_to_goal(quat, goal_quat) -> tuple[float, np.ndarray]:
    """(angle [rad], rotation vector [rad] (3,)) from a goal orientation to ``quat``, both
    (x, y, z, w): ``orientation_error(quat, goal_quat)`` and
    ``quat_log(relative_quat(quat, goal_quat))``, to the last bit, for one state (Python floats
    in the order the array functions sum and multiply; their ``arccos``, ``arctan2`` and the
    3-vector's dot product are numpy's own)."""
    ax, ay, az, aw = quat.tolist() if hasattr(quat, "tolist") else quat
    gx, gy, gz, gw = goal_quat.tolist() if hasattr(goal_quat, "tolist") else goal_quat
    dot = abs(((ax * gx + ay * gy) + az * gz) + aw * gw)
    angle = float(2.0 * np.arccos(min(max(dot, 0.0), 1.0)))  # = np.clip, NaN kept
    na = math.sqrt(((ax * ax + ay * ay) + az * az) + aw * aw)
    nb = math.sqrt(((gx * gx + gy * gy) + gz * gz) + gw * gw)
    if na == 0.0 or nb == 0.0:  # a zero quaternion: numpy's 0/0 (NaN, and its warning)
        return angle, quat_log(relative_quat(quat, goal_quat))
    ax, ay, az, aw = ax / na, ay / na, az / na, aw / na
    bx, by, bz, bw = -(gx / nb), -(gy / nb), -(gz / nb), gw / nb  # the inverse
    x, y, z, w = _product(ax, ay, az, aw, bx, by, bz, bw)
    v = np.array((x, y, z))
    if not w >= 0.0:
        v, w = -v, -w
    n = math.sqrt(v.dot(v))
    if n < 1e-12:
        return angle, 2.0 * v
    return angle, float(2.0 * np.arctan2(n, w) / n) * v


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
    cos = min(max((rel.trace() - 1.0) / 2.0, -1.0), 1.0)  # = np.clip(…, -1, 1), NaN kept
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


def orientation_errors_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angles [rad] (N, M) between every unit quaternion of a (N, 4) and of b (M, 4), in [0, π]
    (:func:`orientation_error` of each pair, as one product)."""
    dot = np.abs(np.clip(np.einsum("id,jd->ij", a, b), -1.0, 1.0))
    return 2.0 * np.arccos(np.minimum(dot, 1.0))


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


def matrix_to_quat_eigen(m: np.ndarray) -> np.ndarray:
    """The quaternion (x, y, z, w) of one rotation matrix m (3, 3) by Eigen's conversion (the
    trace branch, else the largest diagonal entry's; w not made ≥ 0), the numbers of
    pinocchio's ``SE3ToXYZQUAT`` and ``Quaternion(R)``; scalar code that numba compiles
    (:mod:`tamedpuma.robot.point_motion`)."""
    out = np.empty(4)
    t = m[0, 0] + m[1, 1] + m[2, 2]
    if t > 0.0:
        t = math.sqrt(t + 1.0)
        out[3] = 0.5 * t
        t = 0.5 / t
        out[0] = (m[2, 1] - m[1, 2]) * t
        out[1] = (m[0, 2] - m[2, 0]) * t
        out[2] = (m[1, 0] - m[0, 1]) * t
    else:
        i = 0
        if m[1, 1] > m[0, 0]:
            i = 1
        if m[2, 2] > m[i, i]:
            i = 2
        j = (i + 1) % 3
        k = (j + 1) % 3
        t = math.sqrt(m[i, i] - m[j, j] - m[k, k] + 1.0)
        out[i] = 0.5 * t
        t = 0.5 / t
        out[3] = (m[k, j] - m[j, k]) * t
        out[j] = (m[j, i] + m[i, j]) * t
        out[k] = (m[k, i] + m[i, k]) * t
    return out


def quats_to_matrices(q: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) (x, y, z, w) → rotation matrices (..., 3, 3) (normalised first)."""
    q = np.asarray(q, float)
    return unit_quats_to_matrices(q / np.linalg.norm(q, axis=-1, keepdims=True))


def unit_quats_to_matrices(q: np.ndarray) -> np.ndarray:
    """Unit quaternions (..., 4) (x, y, z, w) → rotation matrices (..., 3, 3), not normalised
    (a quaternion of norm s gives s² times a rotation plus (1 − s²) I)."""
    x, y, z, w = np.moveaxis(q, -1, 0)
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


def bullet_rotation_matrices(quat: np.ndarray) -> np.ndarray:
    """Rotation matrices (k, 3, 3) of quaternions (k, 4) (x, y, z, w), operation for operation
    as Bullet's ``btMatrix3x3::setRotation`` (what ``pybullet.getMatrixFromQuaternion`` returns,
    to the last bit): with ``s = 2/|q|²``,
    ``R = [[1 − s(y² + z²), s(xy − wz), s(xz + wy)], [s(xy + wz), 1 − s(x² + z²), s(yz − wx)],
    [s(xz − wy), s(yz + wx), 1 − s(x² + y²)]]``."""
    x, y, z, w = (np.asarray(quat, dtype=float)[:, i] for i in range(4))
    s = 2.0 / (x * x + y * y + z * z + w * w)
    xs, ys, zs = x * s, y * s, z * s
    wx, wy, wz = w * xs, w * ys, w * zs
    xx, xy, xz = x * xs, x * ys, x * zs
    yy, yz, zz = y * ys, y * zs, z * zs
    return np.stack([1.0 - (yy + zz), xy - wz, xz + wy,
                     xy + wz, 1.0 - (xx + zz), yz - wx,
                     xz - wy, yz + wx, 1.0 - (xx + yy)], axis=-1).reshape(-1, 3, 3)
