"""Task maps of the fabric's leaves, vectorised over every (body sphere × obstacle) pair.

Each function maps joint-space kinematics to one-dimensional (or 3-d) task variables and returns,
for the whole batch at once, the task position x, velocity ẋ, the curvature term ``J̇q̇`` (so that
``ẍ = J q̈ + J̇q̇``) and what the pullback needs of the Jacobian. Barrier distances below the margin
are clamped up to it and counted (never a negative or zero barrier distance).

Shapes: k body spheres, n obstacles (run-time data, 0 allowed), 7 (= n_q) joints.
numpy only.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from tamedpuma.robot.rotations import skew


@dataclass(slots=True)
class PairTerms:
    """Sphere-obstacle pair task variables ``x_ij = ‖c_i − o_j‖/(r_i + r_j) − 1`` [1].

    x: (k, n) clamped to ≥ margin; xd: (k, n) ẋ from the relative velocity ``J_i q̇ − ȯ_j`` [1/s];
    jdqd: (k, n) ``J̇q̇`` of the pair [1/s²]; u: (3, k, n) ``ν_ij/(r_i + r_j)`` [1/m] (component
    first), so that the pair's Jacobian row is ``u_ijᵀ J_i``; clearance: (k, n)
    ``‖c_i − o_j‖ − r_i − r_j`` [m]; n_clamped: number of pairs whose x lies below the margin
    before clamping.
    """

    x: np.ndarray
    xd: np.ndarray
    jdqd: np.ndarray
    u: np.ndarray
    clearance: np.ndarray
    n_clamped: int


def sphere_obstacle_pairs(centers, jacobians, jdqd, radii, qd, obs_centers, obs_radii,
                          obs_velocities, margin: float) -> PairTerms:
    """Task variables of every (body sphere i, obstacle j) pair, vectorised.

    centers (k, 3) [m], jacobians (k, 3, dof), jdqd (k, 3) [m/s²], radii (k,) [m]: body spheres;
    qd (dof,) [rad/s]; obs_centers (n, 3) [m], obs_radii (n,) [m], obs_velocities (n, 3) [m/s]
    (constant-velocity obstacles: ``ö_j = 0``); margin: lower clamp of x [1].

    With ``d = c_i − o_j``, ``ν = d/‖d‖``, ``R = r_i + r_j``, ``v = J_i q̇ − ȯ_j``:
    ``x = ‖d‖/R − 1``, ``ẋ = νᵀv/R``, Jacobian row ``νᵀJ_i/R``,
    ``J̇q̇ = (νᵀ J̇_i q̇ + (‖v‖² − (νᵀv)²)/‖d‖)/R`` (from ``ν̇ = (I − ννᵀ) v/‖d‖``).
    Arrays are laid out component-first, (3, k, n), so every operation runs over contiguous pairs.
    """
    k, n = centers.shape[0], obs_centers.shape[0]
    Y = np.empty((3, 3, k, n))
    np.subtract(centers.T[:, :, None], obs_centers.T[:, None, :], out=Y[0])
    np.subtract((jacobians @ qd).T[:, :, None], obs_velocities.T[:, None, :], out=Y[1])
    Y[2] = jdqd.T[:, :, None]
    G = np.einsum("adkn,bdkn->abkn", Y[:2], Y)  # [[d·d, d·v, d·J̇q̇], [v·d, v·v, v·J̇q̇]]
    dist = np.sqrt(G[0, 0])
    np.maximum(dist, 1e-12, out=dist)
    inv_d = 1.0 / dist
    big_r = radii[:, None] + obs_radii
    inv_r = 1.0 / big_r
    x = dist * inv_r
    x -= 1.0
    n_clamped = 0
    if x.size and x.min() < margin:
        n_clamped = int(np.count_nonzero(x < margin))
        np.maximum(x, margin, out=x)
    w = inv_d * inv_r
    nv = G[0, 1] * inv_d
    jd = G[1, 1] - nv * nv
    jd += G[0, 2]
    jd *= w
    return PairTerms(x=x, xd=G[0, 1] * w, jdqd=jd, u=Y[0] * w, clearance=dist - big_r,
                     n_clamped=n_clamped)


def pull_sphere_pairs(m, b_geometry, b_energy, u, jacobians):
    """Pull back all pair specs through their sphere Jacobians, aggregated per sphere.

    m: (k, n) pair metrics; b_geometry, b_energy: (k, n) pulled task forces ``f_p + m_p (J̇q̇)_p``
    of the geometry and of the energy; u: (3, k, n) pair directions (row ``a_ij = u_ijᵀ J_i``);
    jacobians (k, 3, dof). Uses ``Σ_ij m a aᵀ = Σ_i J_iᵀ S_i J_i`` with
    ``S_i = Σ_j m_ij u_ij u_ijᵀ`` (3×3) and ``Σ_ij b a = Σ_i J_iᵀ g_i``, ``g_i = Σ_j b_ij u_ij``:
    one batched product gives ``[S_i | g_i]``. Returns M (dof, dof) and F (2, dof) (rows:
    geometry, energy).
    """
    k = m.shape[0]
    Z = np.empty((5,) + m.shape)
    np.multiply(u, m, out=Z[:3])
    Z[3] = b_geometry
    Z[4] = b_energy
    P = Z.transpose(1, 0, 2) @ u.transpose(1, 2, 0)  # (k, 5, 3): rows S_i (3), g_geom, g_energy
    flat = jacobians.reshape(3 * k, -1)
    M = flat.T @ (P[:, :3] @ jacobians).reshape(3 * k, -1)
    F = P[:, 3:].transpose(1, 0, 2).reshape(2, 3 * k) @ flat
    return M, F


@dataclass(slots=True)
class LimitTerms:
    """Joint-limit task variables: x (2 n_q,) = [q − q_min, q_max − q] clamped to ≥ margin [rad],
    xd (2 n_q,) = [q̇, −q̇] [rad/s]; Jacobian rows ±e_k, ``J̇q̇ = 0``; n_clamped: count below the
    margin (a start on or past a limit)."""

    x: np.ndarray
    xd: np.ndarray
    n_clamped: int


def joint_limits(q, qd, q_min, q_max, margin: float) -> LimitTerms:
    """Distances to both joint limits of every joint (see :class:`LimitTerms`).

    q, qd (n_q,) [rad], [rad/s]; q_min, q_max (n_q,) [rad]; margin [rad].
    """
    x = np.concatenate((q - q_min, q_max - q))
    n_clamped = 0
    if x.min() < margin:
        n_clamped = int(np.count_nonzero(x < margin))
        np.maximum(x, margin, out=x)
    return LimitTerms(x=x, xd=np.concatenate((qd, -qd)), n_clamped=n_clamped)


@dataclass(slots=True)
class GroundTerms:
    """Ground-plane task variables per body sphere: ``x_i = c_{i,z} − r_i − z₀`` clamped [m],
    ``ẋ = (J_i q̇)_z`` [m/s], ``J̇q̇ = (J̇_i q̇)_z`` [m/s²], Jacobian row ``(J_i)_z``."""

    x: np.ndarray
    xd: np.ndarray
    jdqd: np.ndarray
    rows: np.ndarray
    clearance: np.ndarray
    n_clamped: int


def ground_plane(centers, jacobians, jdqd, radii, qd, height: float, margin: float) -> GroundTerms:
    """Ground-plane leaf task variables (plane z = height [m]); see :class:`GroundTerms`."""
    clearance = centers[:, 2] - radii - height
    n_clamped = int(np.count_nonzero(clearance < margin))
    rows = jacobians[:, 2, :]
    return GroundTerms(x=np.maximum(clearance, margin), xd=rows @ qd, jdqd=jdqd[:, 2],
                       rows=rows, clearance=clearance, n_clamped=n_clamped)


@dataclass(slots=True)
class GoalTerms:
    """Goal-attractor task variables: K = 1 + A three-dimensional errors.

    e (K, 3): ``[p_ee − p_g; R_ee a_k − R_g a_k …]`` [m]; jacobians (K, 3, dof + 1): the task
    Jacobians (columns 0…dof − 1) with ``J̇q̇`` appended as the last column [m/s²] (one
    product then pulls back both the metric and the curvature force). Block 0 is the position
    error.
    """

    e: np.ndarray
    jacobians: np.ndarray


def goal_errors(ee_position, ee_rotation, ee_jacobian, ee_jdqd, qd, goal_position,
                goal_rotation, offsets) -> GoalTerms:
    """Position and orientation-vector errors of the end effector to the goal pose.

    ee_position (3,) [m], ee_rotation (3, 3), ee_jacobian (6, dof) rows [v; ω], ee_jdqd (6,) = J̇q̇,
    qd (dof,); goal_position (3,) [m], goal_rotation (3, 3); offsets (A, 3) local vectors a_k [m].
    Orientation: ``x_k = R_ee a_k``, ``J_k = −[x_k]× J_ω``,
    ``J̇q̇_k = −[x_k]× (J̇q̇)_ω + ω (ωᵀx_k) − x_k ‖ω‖²`` (= ``… + ω × (ω × x_k)``), ``ω = J_ω q̇``;
    the target ``R_g a_k`` is fixed. Aligning two non-parallel vectors fixes the orientation.
    """
    ext = np.concatenate((ee_jacobian, ee_jdqd[:, None]), axis=1)
    K = 1 + offsets.shape[0]
    e = np.empty((K, 3))
    jac = np.empty((K, 3, ext.shape[1]))
    np.subtract(ee_position, goal_position, out=e[0])
    jac[0] = ext[:3]
    if K > 1:
        vecs = offsets @ ee_rotation.T
        np.subtract(vecs, offsets @ goal_rotation.T, out=e[1:])
        np.matmul(skew(-vecs), ext[3:], out=jac[1:])
        omega = ext[3:, :-1] @ qd
        jac[1:, :, -1] += (vecs @ omega)[:, None] * omega - (omega @ omega) * vecs
    return GoalTerms(e=e, jacobians=jac)
