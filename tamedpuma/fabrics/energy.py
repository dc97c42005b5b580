"""Lagrangian (Finsler) energies, their metrics and forces, and energization (method.md section 2).

For an energy ``L(x, ẋ)`` the Euler-Lagrange equation ``d/dt ∂L/∂ẋ − ∂L/∂x = 0`` reads
``M_L ẍ + f_L = 0`` with

- metric ``M_L = ∂²L/∂ẋ²``,
- force ``f_L = (∂²L/∂ẋ∂x) ẋ − ∂L/∂x``,
- energy (Hamiltonian) ``H_L = ẋᵀ ∂L/∂ẋ − L``, conserved by that equation.

Energization of a system ``ẍ = a(x, ẋ)`` (a geometry, ``a = −h``) with respect to L:
``ẍ = a − α ẋ`` with ``α = ẋᵀ(M_L a + f_L) / (ẋᵀ M_L ẋ)``, which is method.md's
``energize_L[h] = h + α ẋ``, ``α = −ẋᵀ(M_L h − f_L)/(ẋᵀ M_L ẋ)``. It makes ``dH_L/dt = 0``
and, for an HD2 geometry (``h(x, λẋ) = λ² h(x, ẋ)``), changes only the speed along the path,
not the path.

numpy only; every function works elementwise on arrays of task variables.
"""

from __future__ import annotations

import math

import numpy as np

from tamedpuma.fabrics.gains import BarrierGains, FabricGains


def activation_taper(x, activation: float):
    """Taper ``w(x) = (1 − (x/x_a)²)²`` for ``x < x_a``, 0 beyond, and ``w'(x)`` [1/task units].

    x: (…) barrier distance [task units]; activation x_a > 0 (``inf``: ``w = 1``, ``w' = 0``
    exactly). C¹ at x_a (w and w' both reach 0); flat at the barrier (``w = 1 − 2(x/x_a)² + …``,
    ``w'(0) = 0``), so near an obstacle the leaf is the reference's. Returns ``(w, w')``.
    """
    x = np.asarray(x, dtype=float)
    if not np.isfinite(activation):
        return np.ones_like(x), np.zeros_like(x)
    t = np.maximum(1.0 - (x / activation) ** 2, 0.0)
    return t * t, (-4.0 / activation ** 2) * x * t


def barrier_energy(x, xd, gains: BarrierGains, activation: float = np.inf):
    """Energy ``L = k s(ẋ) w(x) ẋ²/x^p`` of a barrier leaf and its Euler-Lagrange terms.

    x: (…) distance to the barrier, > 0 [task units]; xd: (…) its rate ẋ [task units/s];
    k = gains.energy_gain, p = gains.energy_exponent, s(ẋ) = [ẋ < 0] if gains.energy_directional;
    w: the activation taper of :func:`activation_taper` (``activation`` x_a; ``inf``: w = 1, the
    reference's energy). Returns ``(L, M_L, f_L, H_L)`` with ``M_L = 2 k s w / x^p``,
    ``f_L = ∂²L/∂ẋ∂x ẋ − ∂L/∂x = k s ẋ² (w' − p w/x)/x^p``, ``H_L = L`` (s is piecewise
    constant, so it contributes no derivative). With x_a finite the leaf vanishes (metric, force
    and energy) beyond x_a: far obstacles cost nothing, however many there are (the cost of a step
    at 1000 obstacles is that of the pairs near the arm).
    """
    x = np.asarray(x, dtype=float)
    xd = np.asarray(xd, dtype=float)
    w, dw = activation_taper(x, activation)
    inv = gains.energy_gain * x ** (-gains.energy_exponent)
    if gains.energy_directional:
        inv = inv * (xd < 0)
    xd2 = xd * xd
    lag = inv * w * xd2
    force = inv * xd2 * (dw - gains.energy_exponent * w / x)
    return lag, 2.0 * inv * w, force, lag


def barrier_geometry(x, xd, gains: BarrierGains):
    """Geometry ``ẍ = −h`` of a barrier leaf, ``h = −k s(ẋ) ẋ²/x^p`` (HD2 in ẋ), elementwise.

    x: (…) distance, > 0; xd: (…) rate; k = gains.geometry_gain, p = gains.geometry_exponent,
    s(ẋ) = [ẋ < 0] if gains.geometry_directional. Returns h [task units/s²].
    """
    x = np.asarray(x, dtype=float)
    xd = np.asarray(xd, dtype=float)
    h = -gains.geometry_gain * xd * xd * x ** (-gains.geometry_exponent)
    if gains.geometry_directional:
        h = h * (xd < 0)
    return h


def barrier_leaf(x, xd, gains: BarrierGains, activation: float = np.inf):
    """Everything a barrier leaf contributes, elementwise (the readable reference of the fused
    kernel): ``(m, f, f_L, H)`` with the leaf metric ``m = M_L`` (the energy's metric weighting
    the geometry), geometry force ``f = M_L h`` (spec ``(M_L, M_L h)``), energy force f_L and
    energy H, from :func:`barrier_energy` (with its activation taper) and
    :func:`barrier_geometry`.
    """
    _, m, f_energy, H = barrier_energy(x, xd, gains, activation)
    return m, m * barrier_geometry(x, xd, gains), f_energy, H


def base_energy(qd, gains: FabricGains):
    """Base energy ``L_b = ½ m_b ‖q̇‖²`` [rad²/s²]: metric ``m_b I``, force 0, ``H_b = L_b``."""
    qd = np.asarray(qd, dtype=float)
    return 0.5 * gains.base_metric * float(qd @ qd)


def attractor_potential(e, gains: FabricGains, weight: float):
    """Goal potential ``ψ(e) = k w (‖e‖ + log(1 + exp(−2 a ‖e‖)) / a)`` and its gradient.

    e: (…, d) error to the goal [m]; k = gains.goal_potential_gain, a = gains.goal_sharpness,
    w = weight. ``∇ψ = k w tanh(a ‖e‖) e/‖e‖`` (→ 0 smoothly at e = 0), ψ(0) = k w log(2)/a.
    Returns ``(ψ (…), ∇ψ (…, d), ‖e‖ (…))``.
    """
    e = np.asarray(e, dtype=float)
    r = np.sqrt(np.einsum("...d,...d->...", e, e))
    a = gains.goal_sharpness
    k = gains.goal_potential_gain * np.asarray(weight, dtype=float)
    psi = k * (r + np.logaddexp(0.0, -2.0 * a * r) / a)
    # tanh(a r)/r → a as r → 0; below 1e-12 m the gradient is ≈ 0 either way.
    ratio = np.tanh(a * r) / np.maximum(r, 1e-12)
    return psi, (k * ratio)[..., None] * e, r


def attractor_metric(r, gains: FabricGains):
    """Scalar goal metric ``g(‖e‖) = s ((G_max − G_min) exp(−(w ‖e‖)²) + G_min)``; metric g I.

    r: (…) error norm ‖e‖ [m]. It is ``∂²L/∂ẋ²`` of the attractor energy
    ``L = ½ g(‖e‖) ‖ẋ‖²`` (s = gains.goal_metric_scale = 2 reproduces the reference's
    ``L = ẋᵀ G ẋ``). Returns g (…) [1].
    """
    r = np.asarray(r, dtype=float)
    w = gains.goal_metric_width
    return gains.goal_metric_scale * (
        (gains.goal_metric_max - gains.goal_metric_min) * np.exp(-(w * r) ** 2)
        + gains.goal_metric_min)


def attractor(e, gains: FabricGains, weight):
    """Potential, gradient, distance and metric of the goal attractor in one pass.

    e (K, d) errors [m]; weight (K,) or scalar. Returns ``(ψ (K,), ∇ψ (K, d), ‖e‖ (K,), g (K,))``
    exactly as :func:`attractor_potential` and :func:`attractor_metric`, vectorised.
    """
    r2 = np.einsum("kd,kd->k", e, e)
    r = np.sqrt(r2)
    a = gains.goal_sharpness
    k = gains.goal_potential_gain * weight
    psi = k * (r + np.logaddexp(0.0, (-2.0 * a) * r) / a)
    ratio = np.tanh(a * r)
    ratio *= k
    ratio /= np.maximum(r, 1e-12)
    s = gains.goal_metric_scale
    gm = np.exp((-gains.goal_metric_width ** 2) * r2)
    gm *= s * (gains.goal_metric_max - gains.goal_metric_min)
    gm += s * gains.goal_metric_min
    return psi, ratio[:, None] * e, r, gm


def attractor_blocks(r2, gains: FabricGains, weights):
    """:func:`attractor` for a few blocks in plain floats (cheaper than arrays for K ≤ 4).

    r2: squared error norms ``‖e_k‖²`` [m²] (sequence); weights: w_k (sequence).
    Returns ``(ψ = Σ_k ψ_k, [‖e_k‖], [c_k], [g_k])`` where ``∇ψ_k = c_k e_k``,
    ``c_k = k w_k tanh(a ‖e_k‖)/‖e_k‖`` [1/s²] and g_k is the metric of block k.
    """
    a = gains.goal_sharpness
    c0 = -gains.goal_metric_width ** 2
    c1 = gains.goal_metric_scale * (gains.goal_metric_max - gains.goal_metric_min)
    c2 = gains.goal_metric_scale * gains.goal_metric_min
    psi = 0.0
    rs, ratios, metrics = [], [], []
    for rr, w in zip(r2, weights):
        r = math.sqrt(rr)
        k = gains.goal_potential_gain * w
        psi += k * (r + math.log1p(math.exp(-2.0 * a * r)) / a)
        rs.append(r)
        ratios.append(k * math.tanh(a * r) / max(r, 1e-12))
        metrics.append(c1 * math.exp(c0 * rr) + c2)
    return psi, rs, ratios, metrics


def energization_coefficient(qd, M_L, f_L, qdd, eps: float = 1e-6):
    """α such that ``q̈ = a − α q̇`` conserves ``H_L``: ``α = q̇ᵀ(M_L a + f_L)/(q̇ᵀ M_L q̇ + ε)``.

    qd: (n,) [rad/s]; M_L: (n, n) energy metric; f_L: (n,) energy force (both in joint space,
    i.e. pulled back); qdd: (n,) the system's acceleration a [rad/s²]; ε [(rad/s)²] keeps α finite
    at rest. Returns α [1/s].
    """
    qd = np.asarray(qd, dtype=float)
    Mqd = M_L @ qd
    return float((Mqd @ qdd + qd @ f_L) / (qd @ Mqd + eps))


def energize(qd, M_L, f_L, qdd, eps: float = 1e-6):
    """``energize_L``: returns ``(a − α q̇, α)`` with α from :func:`energization_coefficient`."""
    alpha = energization_coefficient(qd, M_L, f_L, qdd, eps)
    return np.asarray(qdd, dtype=float) - alpha * np.asarray(qd, dtype=float), alpha


def execution_alpha(qd, qdd, eps: float = 1e-6):
    """α that conserves the execution energy ``L_ex = ‖q̇‖²`` (metric 2I, force 0) for ``q̈ = a``:
    ``α = q̇ᵀ a / (‖q̇‖² + ε)`` [1/s]; qd (n,) [rad/s], qdd (n,) [rad/s²]."""
    qd = np.asarray(qd, dtype=float)
    return float(qd @ qdd / (qd @ qd + eps))
