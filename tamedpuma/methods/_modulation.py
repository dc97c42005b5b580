"""Dynamical-system modulation around sphere obstacles (Khansari-Zadeh and Billard 2012).

numpy only. All positions are in ONE frame, the robot base (= world) frame: the modulated point
is the end-effector position x [m] and the obstacles are spheres (centre o_j [m], radius r_j [m],
velocity ȯ_j [m/s]) in that same frame.

For each obstacle j, with the safety-inflated radius ``R_j = r_j + r_safety``:

- distance function ``Γ_j(x) = (‖x − o_j‖ / R_j)^(2p)``: 1 on the inflated boundary, > 1 outside,
  → ∞ far away (``p`` ≥ 1/2 the order; p = 1 gives the squared-distance form);
- unit normal ``n_j = (x − o_j)/‖x − o_j‖`` (the direction of ∇Γ_j for a sphere) and two unit
  tangents completing an orthonormal basis ``E_j = [n_j, t_1, t_2]`` (so ``E_j⁻¹ = E_jᵀ``);
- eigenvalues ``D_j = diag(1 − ω_j/Γ_j, 1 + ω_j/Γ_j, 1 + ω_j/Γ_j)``;
- modulation ``M_j = E_j D_j E_jᵀ = (1 + ω_j/Γ_j) I − (2 ω_j/Γ_j) n_j n_jᵀ`` (independent of which
  tangents are chosen, hence continuous in x).

Several obstacles: the *weighted product* of Khansari-Zadeh and Billard (2012, eqs. 19-20),
``M(x) = Π_j M_j(x)`` (product in the order the obstacles are given) with weights

    ω_j = Π_{i ≠ j} (Γ_i − 1) / ((Γ_j − 1) + (Γ_i − 1))     (ω_j = 1 for a single obstacle),

so that on the boundary of obstacle j (Γ_j = 1) ω_j = 1 and every other M_i is the identity: the
normal eigenvalue there is exactly 0 and the flow cannot enter the obstacle. Far from every
obstacle (all Γ → ∞) M → I.

Moving obstacles are handled in the obstacle frame: the relative velocity is modulated and the
obstacle velocity added back, ``ẋ = M(x) (f(x) − ȯ) + ȯ``, with ``ȯ = Σ_j ω̂_j ȯ_j`` and
``ω̂_j = ω_j / Σ_i ω_i`` (so ȯ = ȯ_j on the boundary of obstacle j, and far away M → I makes ȯ
cancel).

Inside an inflated sphere (Γ < 1, only after a disturbance) Γ is floored at ``gamma_floor``
(default 0.5) in the eigenvalues: the normal eigenvalue 1 − 1/Γ is then negative, which reverses an
inward velocity (pushes the point out) and stays bounded; the weights use max(Γ − 1, 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: Weight denominators below this count as 0 (two boundaries touching) [-].
_EPS = 1e-12


@dataclass(frozen=True)
class Modulation:
    """The modulation at one point.

    matrix: (3, 3) M(x) [-]; gamma: (n,) Γ_j(x) [-]; weights: (n,) ω_j [-];
    obstacle_velocity: (3,) the weighted obstacle velocity ȯ [m/s].
    """

    matrix: np.ndarray
    gamma: np.ndarray
    weights: np.ndarray
    obstacle_velocity: np.ndarray

    @property
    def gamma_min(self) -> float:
        """min_j Γ_j [-] (inf without obstacles)."""
        return float(self.gamma.min()) if len(self.gamma) else float("inf")


def gamma(x: np.ndarray, centers: np.ndarray, radii: np.ndarray, safety: float = 0.0,
          power: float = 1.0) -> np.ndarray:
    """``Γ_j(x) = (‖x − o_j‖ / (r_j + safety))^(2 power)`` for every obstacle: (n,) [-].

    x: (3,) [m]; centers: (n, 3) [m]; radii: (n,) [m]; safety: margin added to r_j [m].
    """
    dist = np.linalg.norm(np.asarray(x, float)[None, :] - np.reshape(centers, (-1, 3)), axis=1)
    return _gamma(dist, radii, safety, power)


def _gamma(dist: np.ndarray, radii: np.ndarray, safety: float, power: float) -> np.ndarray:
    """Γ_j from the distances ‖x − o_j‖ (n,) [m] (:func:`gamma`)."""
    return (dist / (np.asarray(radii, float) + safety)) ** (2.0 * power)


def weights(gammas: np.ndarray) -> np.ndarray:
    """Khansari-Billard weights ``ω_j = Π_{i≠j} (Γ_i − 1)/((Γ_j − 1) + (Γ_i − 1))``: (n,) [-].

    Uses max(Γ − 1, 0); a 0/0 factor (both points on a boundary) counts as 1/2.
    """
    g = np.maximum(np.asarray(gammas, float) - 1.0, 0.0)
    n = len(g)
    if n <= 1:
        return np.ones(n)
    num = g[None, :]                                    # [j, i] = Γ_i − 1 (broadcast)
    den = g[:, None] + num                              # [j, i] = (Γ_j − 1) + (Γ_i − 1)
    apart = den > _EPS
    factor = np.where(apart, num / np.where(apart, den, 1.0), 0.5)
    factor.flat[::n + 1] = 1.0                          # the diagonal, i = j
    return factor.prod(axis=1)


def orthonormal_basis(normal: np.ndarray) -> np.ndarray:
    """``E = [n, t_1, t_2]``: (3, 3) orthonormal, first column the unit normal (any tangents)."""
    n = np.asarray(normal, float) / np.linalg.norm(normal)
    helper = np.eye(3)[int(np.argmin(np.abs(n)))]
    t1 = np.cross(n, helper)
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(n, t1)
    return np.column_stack((n, t1, t2))


def modulation(x: np.ndarray, centers: np.ndarray, radii: np.ndarray,
               velocities: np.ndarray | None = None, safety: float = 0.0, power: float = 1.0,
               gamma_floor: float = 0.5) -> Modulation:
    """The modulation M(x) of all obstacles and the weighted obstacle velocity (module docstring).

    x: (3,) point [m]; centers: (n, 3) [m]; radii: (n,) [m]; velocities: (n, 3) [m/s] or None
    (static); safety: margin added to every radius [m]; power: p of Γ; gamma_floor: lower bound on
    Γ used in the eigenvalues (> 0).
    """
    x = np.asarray(x, float)
    centers = np.reshape(np.asarray(centers, float), (-1, 3))
    n = len(centers)
    vel = np.zeros((n, 3)) if velocities is None else np.reshape(velocities, (n, 3))
    if n == 0:
        return Modulation(np.eye(3), np.zeros(0), np.zeros(0), np.zeros(3))
    diff = x[None, :] - centers
    dist = np.linalg.norm(diff, axis=1)  # (n,), Γ's and the normals' distances
    gam = _gamma(dist, radii, safety, power)
    w = weights(gam)
    # at the exact centre the normal is undefined: any unit vector (here +z) keeps M finite
    far = (dist > _EPS)[:, None]
    normals = np.where(far, diff / np.where(far, dist[:, None], 1.0), [0.0, 0.0, 1.0])
    inv = (w / np.maximum(gam, gamma_floor))[:, None, None]  # ω_j / Γ_j
    # every M_j = (1 + ω_j/Γ_j) I − (2 ω_j/Γ_j) n_j n_jᵀ at once; M = M_1 M_2 … (I M_1 = M_1)
    m = (1.0 + inv) * np.eye(3) - (2.0 * inv) * (normals[:, :, None] * normals[:, None, :])
    matrix = m[0]
    for j in range(1, n):
        matrix = matrix @ m[j]
    total = w.sum()
    o_dot = (w[:, None] * vel).sum(axis=0) / total if total > _EPS else vel.mean(axis=0)
    return Modulation(matrix, gam, w, o_dot)


def modulate(velocity: np.ndarray, x: np.ndarray, centers: np.ndarray, radii: np.ndarray,
             velocities: np.ndarray | None = None, safety: float = 0.0, power: float = 1.0,
             gamma_floor: float = 0.5) -> tuple[np.ndarray, Modulation]:
    """Modulated velocity ``ẋ = M(x)(f − ȯ) + ȯ`` [m/s] of the nominal velocity f (3,) [m/s] at x.

    Returns (ẋ (3,), the :class:`Modulation`). Arguments as :func:`modulation`.
    """
    mod = modulation(x, centers, radii, velocities, safety, power, gamma_floor)
    f = np.asarray(velocity, float)
    return mod.matrix @ (f - mod.obstacle_velocity) + mod.obstacle_velocity, mod
