"""Speed control of a forced fabric (Ratliff et al. 2020, as the reference planner; method.md §2).

Given the unforced geometry ``q̈_G = −M⁻¹ f`` and the forced system ``q̈_F = −(M + M_ψ)⁻¹(f + f_ψ)``:

- ``α⁰ = execution_alpha(q̇, q̈_G)`` and ``α^ψ = execution_alpha(q̇, q̈_F)`` conserve the execution
  energy ``L_ex = ‖q̇‖²`` of the unforced and the forced system;
- ``α_ex = η α⁰ + (1 − η) α^ψ`` with ``η = ½(tanh(−η_g ‖q̇‖² − η_s) + 1)`` (η → 0 at speed: the
  forcing then only steers; at rest η ≈ 0.27 lets the forcing inject energy);
- ``β = ½ β_c (tanh(−β_s (‖e‖ − r_β)) + 1) + β_far + max(0, α_G − α_ex)`` where α_G energizes the
  unforced geometry w.r.t. the fabric's own energy L_e: the last term makes the damping at least
  what keeps ``H_{L_e} + ψ`` decreasing;
- ``q̈ = q̈_F − (α_ex + β) q̇``.

numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tamedpuma.fabrics.gains import FabricGains


def eta(speed_sq: float, gains: FabricGains) -> float:
    """Blend ``η = ½(tanh(−eta_gain ‖q̇‖² − eta_shift) + 1)`` ∈ (0, 1); speed_sq = ‖q̇‖² [rad²/s²]."""
    return 0.5 * (math.tanh(-gains.eta_gain * speed_sq - gains.eta_shift) + 1.0)


def damping(goal_distance: float, alpha_geometry: float, alpha_ex: float,
            gains: FabricGains) -> float:
    """Damping β [1/s] (see the module docstring); goal_distance ‖e‖ [m], α's [1/s]."""
    close = 0.5 * gains.damping_close * (
        math.tanh(-gains.damping_slope * (goal_distance - gains.damping_radius)) + 1.0)
    return close + gains.damping_far + max(0.0, alpha_geometry - alpha_ex)


@dataclass(slots=True)
class SpeedTerms:
    """Speed-control internals: α⁰, α^ψ, α_ex, η [1], β [1/s]."""

    alpha_0: float
    alpha_psi: float
    alpha_ex: float
    eta: float
    beta: float


def speed_terms(speed_sq: float, qd_dot_qdd_geometry: float, qd_dot_qdd_forced: float,
                alpha_geometry: float, goal_distance: float, gains: FabricGains) -> SpeedTerms:
    """The speed-control scalars from dot products (plain floats, no arrays).

    speed_sq ``‖q̇‖²``; ``q̇ᵀq̈_G`` and ``q̇ᵀq̈_F`` [rad²/s³]; α_G [1/s]; goal_distance ‖e‖ [m].
    """
    denom = speed_sq + gains.energization_eps
    a0 = qd_dot_qdd_geometry / denom
    apsi = qd_dot_qdd_forced / denom
    e = eta(speed_sq, gains)
    aex = e * a0 + (1.0 - e) * apsi
    return SpeedTerms(a0, apsi, aex, e, damping(goal_distance, alpha_geometry, aex, gains))


def speed_control(qd, qdd_geometry, qdd_forced, alpha_geometry: float, goal_distance: float,
                  gains: FabricGains) -> tuple[np.ndarray, SpeedTerms]:
    """``q̈ = q̈_F − (α_ex + β) q̇`` (see the module docstring).

    qd (n,) [rad/s]; qdd_geometry q̈_G and qdd_forced q̈_F (n,) [rad/s²]; alpha_geometry α_G [1/s]
    (energization of q̈_G w.r.t. the fabric energy); goal_distance ‖e‖ [m].
    Returns the acceleration [rad/s²] and the :class:`SpeedTerms`.
    """
    sp = speed_terms(float(qd @ qd), float(qd @ qdd_geometry), float(qd @ qdd_forced),
                     alpha_geometry, goal_distance, gains)
    return qdd_forced - (sp.alpha_ex + sp.beta) * qd, sp
