"""The fabric at the control rate: what a continuous-time law needs to stay safe when it is applied
as one velocity target per control period Δt.

The simulator (and a real velocity-controlled arm) turns q̈ into the next joint velocity
``q̇⁺ = q̇ + Δt q̈``, held for Δt. Three discrete-time facts break the continuous guarantees:

1. **Barriers crossed between samples.** A barrier leaf keeps its distance x > 0 only in continuous
   time; at Δt = 0.02 s a body sphere approaching at ẋ < −x/Δt is inside the obstacle before the
   next evaluation of the fabric. :func:`barrier_step` keeps the linearised next distance positive:
   every barrier row p (Jacobian row a_p, distance x_p, curvature J̇q̇_p) gets the constraint
   ``a_pᵀ q̇⁺ ≥ −κ x_p/Δt − ½Δt min(J̇q̇_p, 0)`` (0 < κ < 1), so
   ``x⁺ ≈ x + Δt a_pᵀq̇⁺ + ½Δt² J̇q̇_p ≥ (1 − κ) x > 0``: a discrete-time barrier (the distance
   shrinks at most geometrically and never crosses, to second order in Δt along the current
   velocity's curvature; exactly for the linear joint-limit rows).
   q̇⁺ is projected onto these half-spaces in the metric M (the closest admissible velocity,
   ``min ‖q̇⁺ − v‖²_M``, one small non-negative least-squares solve when a row is violated).
2. **Velocity limits.** A per-joint clamp ``clip(q̇⁺, ±q̇_max)`` changes the direction of motion, so
   the path is no longer the fabric's (the arm swings off its geometry, e.g. into an obstacle or
   the ground). :func:`limit_speed` instead scales q̇⁺ uniformly, ``q̇⁺ ← s q̇⁺`` with
   ``s = min(1, min_j q̇_max,j / |q̇⁺_j|)``: the speed along the path changes, the direction (and
   the path of an HD2 geometry) does not. The arm then never needs the simulator's clamp.
3. **Velocity-proportional terms.** Energization and damping act as ``q̈ = a + c q̇``; with
   ``|c| Δt > 1`` the explicit step flips or amplifies q̇. :func:`energized_velocity_step` takes
   the ``c q̇`` part implicitly along q̇ alone (c ≤ 0), where it acts.

What is kept: both filters only remove energy. The projection is onto a convex set that contains
q̇⁺ = 0 (the right-hand sides are ≤ 0), so ``‖q̇⁺‖_M`` never grows (non-expansive projection in
the M-norm); the scaling has s ≤ 1. Hence every energy argument of the paper that says "the energy
does not increase" (boundedness, barrier avoidance; CPM's dH/dt ≤ −β q̇ᵀMq̇) still holds, with
extra dissipation where a filter acts. The paths of an HD2 geometry are unchanged by the scaling;
the projection changes the direction only when the next step would otherwise cross a barrier.
numpy only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from tamedpuma.fabrics.spec import linear_solve

# the reductions without their Python wrappers (np.any, np.all, np.min, np.max on 1-d arrays:
# the same ufunc reductions, the same results)
_any, _all = np.logical_or.reduce, np.logical_and.reduce
_min = np.minimum.reduce


@dataclass(frozen=True)
class FarRows:
    """Barrier rows left out of :func:`barrier_step` because they provably cannot be crossed
    within one period: the sphere × obstacle pairs beyond the obstacle leaf's activation
    distance, ``x = ‖d‖/R − 1 ≥ x_a`` (their metric is 0; the fabric builds no row for them).

    Why a far pair is safe. Its row is ``a = νᵀJ_i/R`` (ν = d/‖d‖), its drift ``−νᵀȯ_j/R``
    and its curvature ``J̇q̇ = (νᵀJ̇_iq̇ + (‖v‖² − (νᵀv)²)/‖d‖)/R ≥ −‖J̇_iq̇‖/R``
    (Cauchy-Schwarz), so for a velocity w both of its constraints (with and without the drift)
    ``a·w (+ drift) ≥ −κx/Δt − ½Δt min(J̇q̇, 0)`` hold when
    ``Δt(‖J_i w‖ + ‖ȯ_j‖) + ½Δt²‖J̇_iq̇‖ ≤ κ x R = κ(‖d‖ − R)``, and ``x R ≥ x_a (r_i + r_min)``.
    :meth:`holds` checks that per body sphere i with the largest obstacle speed.

    clearance (k,) [m]: ``x_a (r_i + r_min)``, a lower bound of every left-out pair's clearance
    ``‖d‖ − R`` of body sphere i; jacobians (k, 3, n): the spheres' linear Jacobians J_i;
    jdqd_norm (k,) [m/s²]: ``‖J̇_i q̇‖``; obstacle_speed [m/s]: ``max_j ‖ȯ_j‖``; rows: returns
    the left-out rows ``(rows (F, n), x (F,), J̇q̇ (F,), drift (F,))`` (drift: ``ẋ − a·q̇``)
    when the bound does not hold.
    """

    clearance: np.ndarray
    jacobians: np.ndarray
    jdqd_norm: np.ndarray
    obstacle_speed: float
    rows: Callable[[], tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]
    activation: float = np.inf  # x_a: every left-out pair has x ≥ x_a

    def holds(self, w: np.ndarray, dt: float, kappa: float, standoff: float = 0.0) -> bool:
        """True when no left-out row can be violated at the velocity w (n,) [rad/s] (with or
        without its drift; a relative slack of 1e-9 covers the rounding of the bound). With a
        standoff x_s (:func:`barrier_step`) the bound uses ``(x − x_s) R ≥ x R (1 − x_s/x_a)``
        for x ≥ x_a."""
        jw = self.jacobians @ w  # (k, 3): J_i w
        speed = np.sqrt(np.einsum("kd,kd->k", jw, jw))
        need = dt * (speed + self.obstacle_speed) + 0.5 * dt * dt * self.jdqd_norm
        room = 1.0 - standoff / self.activation if standoff else 1.0
        return bool(np.all(need * (1.0 + 1e-9) <= kappa * room * self.clearance))


def limit_speed(qd_next: np.ndarray, qd_max: np.ndarray) -> tuple[np.ndarray, float]:
    """``(s q̇⁺, s)`` with ``s = min(1, min_j q̇_max,j/|q̇⁺_j|)`` (direction kept) [rad/s], [1].
    A step kernel (methods/_kernels.py compiles it as it stands: numpy calls numba takes)."""
    ratio = np.max(np.abs(qd_next) / qd_max)
    if ratio <= 1.0:
        return qd_next, 1.0
    s = 1.0 / ratio
    return qd_next * s, s


def barrier_step(v: np.ndarray, rows: np.ndarray, x: np.ndarray, dt: float, kappa: float,
                 M: np.ndarray, jdqd: np.ndarray | None = None,
                 drift: np.ndarray | None = None,
                 far: FarRows | None = None, standoff: float = 0.0) -> tuple[np.ndarray, int]:
    """Project the next velocity v (n,) [rad/s] onto ``{w : A w ≥ b}``,
    ``b = −κ (x − x_s)/Δt − ½ Δt min(J̇q̇, 0)``, in the metric M.

    standoff x_s ≥ 0 (in the rows' units): the distance shrinks at most geometrically towards
    x_s instead of towards 0, so that the linearisation's error (second order in Δt) cannot
    take a barrier past 0 when a moving obstacle keeps closing in (with x_s = 0 an arm riding
    such an obstacle at x → 0 crosses it by the linearisation's error).

    rows A (R, n): barrier Jacobian rows ``∂x_p/∂q``; x (R,) barrier distances (in the rows'
    units; ≤ 0 past a barrier: then the row may not approach further); drift (R,): the part
    of ẋ the velocity does not set (a moving obstacle's ``−νᵀȯ/R``; the constraint is then
    ``a·w + drift ≥ b``); dt [s]; kappa
    κ ∈ (0, 1); M (n, n) SPD; jdqd (R,): the rows' curvature J̇q̇ at the current velocity,
    the second-order term of ``x⁺ ≈ x + Δt a·w + ½Δt² J̇q̇`` (only its negative part is kept: a
    curved path that bends
    towards the barrier tightens the constraint, one that bends away never loosens it).
    Returns (w, number of rows active at w).
    Nothing to do (one product) unless a row is violated; then the exact projection
    ``min ½‖w − v‖²_M`` as a least-distance problem (Lawson & Hanson, ch. 23): with M = LLᵀ and
    ``u = Lᵀ(w − v)``, ``min ‖u‖ s.t. G u ≥ h``, ``G = A L⁻ᵀ``, ``h = b − A v``, solved by one
    non-negative least squares ``min_{z ≥ 0} ‖[Gᵀ; hᵀ] z − e_{n+1}‖`` (``u = −r_{1..n}/r_{n+1}``
    for the residual r). Without drift feasible always: w = 0 is admissible since b ≤ 0. With
    a drift that closes a row in, w must move that row away; if that cannot be met together with
    every other row, the projection without the drift is returned.

    far: rows left out of ``rows`` (:class:`FarRows`). The step is taken over ``rows``; if the
    left-out rows provably hold at v and at the answer w (:meth:`FarRows.holds`), w is the
    answer over all rows (each decision of the step and each projection is then the same:
    a projection onto fewer half-spaces that meets the others is the projection onto all, and
    the rows it leaves inactive do not count); otherwise the step is taken again over all rows.
    """
    w, active = _step(v, rows, x, dt, kappa, M, jdqd, drift, standoff)
    if far is None or (far.holds(v, dt, kappa, standoff)
                       and (w is v or far.holds(w, dt, kappa, standoff))):
        return w, active
    f_rows, f_x, f_jd, f_drift = far.rows()  # the bound fails (rare): over every row
    rows, x = np.concatenate((rows, f_rows)), np.concatenate((x, f_x))
    if jdqd is not None:
        jdqd = np.concatenate((jdqd, f_jd))
    if drift is not None:
        drift = np.concatenate((drift, f_drift))
    return _step(v, rows, x, dt, kappa, M, jdqd, drift, standoff)


def _step(v, rows, x, dt, kappa, M, jdqd, drift, standoff=0.0):
    """:func:`barrier_step` over the given rows."""
    b = -kappa * (x - standoff) / dt
    if jdqd is not None:
        b = b - 0.5 * dt * np.minimum(jdqd, 0.0)
    # a row already at or past its standoff (x ≤ x_s, e.g. a base sphere below the ground plane)
    # must not approach further but is not asked to jump out: w = 0 stays admissible (always
    # feasible)
    past = x <= standoff
    b_static = np.where(past, np.minimum(b, 0.0), b) if _any(past) else b
    Av = rows @ v
    free = bool(_all(Av >= b_static))  # the common case: nothing to project (one product)
    if drift is None:
        if free:
            return v, 0
        return _project(v, rows, b_static, M) or (np.zeros_like(v),
                                                   int(np.count_nonzero(b_static == 0.0)))
    # a moving obstacle closes in by itself: ẋ = a·w + drift. First the static projection
    # (feasible: w = 0 admissible), kept if it also meets the drifting rows
    if free:
        w, active = v, 0
        closes = not bool(_all(Av >= b - drift))
    else:
        w, active = _project(v, rows, b_static, M) or (
            np.zeros_like(v), int(np.count_nonzero(b_static == 0.0)))
        closes = not bool(_all(rows @ w >= b - drift))
    if not closes:
        return w, active
    # an approaching obstacle asks the arm to move away: keep that if it can be met with
    # every other row, else the static constraints (w above)
    moved = _project(v, rows, b - drift, M)
    return (w, active) if moved is None else moved


def _project(v: np.ndarray, rows: np.ndarray, b: np.ndarray, M: np.ndarray):
    """``argmin ½‖w − v‖²_M s.t. rows w ≥ b`` and its number of active rows (see
    :func:`barrier_step`); None when no w meets every row."""
    Av = rows @ v
    if _all(Av >= b):
        return v, 0
    L = np.linalg.cholesky(M)  # M = L Lᵀ
    G = linear_solve(L, rows.T).T  # A L⁻ᵀ (R, n)
    h = b - Av
    n = v.shape[0]
    E = np.vstack((G.T, h[None]))
    f = np.zeros(n + 1)
    f[n] = 1.0
    z = nnls(E, f)
    r = E @ z - f
    if not r[n] < -1e-12:  # ‖r‖ = 0: the constraints have no common point
        return None
    u = -r[:n] / r[n]
    w = v + linear_solve(L.T, u)  # L⁻ᵀ u
    return w, int(np.count_nonzero(z > 0))


def nnls(E: np.ndarray, f: np.ndarray, max_iter: int | None = None) -> np.ndarray:
    """``argmin_{z ≥ 0} ‖E z − f‖`` (Lawson & Hanson's active-set NNLS), E (m, k), f (m,)."""
    m, k = E.shape
    z = np.zeros(k)
    passive = np.zeros(k, dtype=bool)
    tol = 1e-12 * max(1.0, float(np.abs(E).max()))
    for _ in range(max_iter or 3 * k + 10):
        w = E.T @ (f - E @ z)
        w[passive] = -np.inf
        j = int(w.argmax())
        if w[j] <= tol:
            break
        passive[j] = True
        while True:
            idx = np.flatnonzero(passive)
            sol = np.linalg.lstsq(E[:, idx], f, rcond=None)[0]
            if _all(sol > 0):
                z[:] = 0.0
                z[idx] = sol
                break
            neg = sol <= 0
            step = _min(z[idx][neg] / (z[idx][neg] - sol[neg]))
            z[idx] += step * (sol - z[idx])
            passive[idx[z[idx] <= tol]] = False
            z[~passive] = 0.0
    return z


def energized_velocity_step(qd: np.ndarray, a: np.ndarray, alpha: float, dt: float,
                            Mqd: np.ndarray, eps: float) -> np.ndarray:
    """Next velocity of ``q̈ = a − α q̇`` over Δt, the ``α q̇`` part taken implicitly along q̇
    alone (α > 0; explicitly otherwise).

    Energization (and every term of the laws proportional to q̇: CPM's regulator and damping)
    acts along q̇ only: energization removes the M-component of the acceleration along q̇,
    ``α q̇ = P a`` with the rank-one ``P x = q̇ (q̇ᵀM x)/(q̇ᵀM q̇ + ε)``. Its implicit step is
    ``(I + αΔt P) q̇⁺ = q̇ + Δt a``, by Sherman-Morrison (w = Mq̇/(q̇ᵀMq̇ + ε), s = wᵀq̇ < 1)::

        q̇⁺ = b − q̇ αΔt (wᵀb)/(1 + αΔt s),   b = q̇ + Δt a

    Along q̇ it is ``(q̇ + Δt a)/(1 + αΔt)`` (never reverses q̇); across q̇ the acceleration
    acts in full, as in the law. Why: α ~ ‖a‖/‖q̇‖ grows without bound at low speed where the
    geometry does not vanish with q̇ (a barrier to an obstacle that moves towards a resting arm),
    and the isotropic ``(q̇ + Δt a)/(1 + αΔt)`` then divides the whole step, the forcing and the
    barriers' push across q̇ with it, by 1 + αΔt: the arm is held still while the obstacle closes
    in. Mqd: ``M q̇`` [M: the energized energy's metric]; eps: ε [(rad/s)²] of α's denominator."""
    b = qd + dt * a
    if not alpha > 0.0:
        return b - dt * alpha * qd
    denom = float(qd @ Mqd) + eps
    k = alpha * dt
    return b - qd * (k * float(Mqd @ b) / denom / (1.0 + k * float(qd @ Mqd) / denom))
