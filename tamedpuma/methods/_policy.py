"""The learned motion primitive seen from joint space: task-space adapters and the pullback.

A PUMA primitive lives in a task space T (end-effector pose on R³×S³ for the arm; the plane for the
point robot). Per control step the TamedPUMA methods need, at (q, q̇):

- the desired task acceleration ``ẍ_d = f_θ^T(x, ẋ)`` with the task Jacobian J and ``J̇q̇``;
- its pullback to joint space (paper eq. 8, method.md §4), with a damped pseudo-inverse
  ``J⁺ = Jᵀ(JJᵀ + λ²I)⁻¹`` and a secondary objective in the null space ``N = I − J⁺J``::

      q̈_C = J⁺ (ẍ_d − J̇q̇) + N q̈_null                      [rad/s²]

- the compatible potential ψ(x) = ‖ρ(x_g, 0) − ρ(x, 0)‖² and ``∂ψ/∂q = (∂ψ/∂x) J`` (paper eq. 11).

Adapters take a primitive object (duck-typed) so tests can use analytic stand-ins:
:class:`PoseTask` wants ``acceleration(p, quat, v, ω, goal_p, goal_quat) -> (a, α)`` and
``potential(p, quat, goal_p, goal_quat) -> (ψ, ∂ψ/∂p, ∂ψ/∂θ)`` (∂θ: world-frame rotation);
:class:`PlanarTask` wants ``acceleration(x, ẋ, goal)`` and ``potential(x, goal) -> (ψ, ∂ψ/∂x)``.
numpy only (the primitive may use torch inside).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from tamedpuma.fabrics.spec import linear_solve
from tamedpuma.robot.kinematics import KinematicState
from tamedpuma.robot.rotations import quat_conj, quat_exp, quat_log, quat_mul


@dataclass(frozen=True)
class TaskAcceleration:
    """xdd (m,) desired task acceleration; J (m, n) task Jacobian; jdqd (m,) = J̇q̇."""

    xdd: np.ndarray
    J: np.ndarray
    jdqd: np.ndarray


class OrientationReference:
    """PUMA's orientation as a reference state (``orientation: reference``): near the goal the
    primitive sees the hand's position and velocity and a reference orientation ``(ζ_r, ω_r)``
    that it moves itself, ``ω̇_r = α(p, ζ_r, ṗ, ω_r)``, ``ζ_r ← exp(ω_r Δt) ζ_r``; the hand's
    orientation rows track it,

        ω̇_d = α + sat_{a_max}(k_p log(ζ_r ζ⁻¹) + k_d (ω_r − ω))                  [rad/s²]

    (sat: the vector scaled down to the norm a_max where it is longer). Farther than ``radius``
    from the goal, or with a body sphere within ``clearance`` of an obstacle, it is off (PUMA's
    feedback law, the same computation); coming on it starts from the hand's ``(ζ, ω)``.

    Why. PUMA's position field depends on the orientation it is evaluated at, and its
    equilibrium is the goal *pose*: with the orientation held 0.47 rad from the goal's (joints 5
    and 7 on their limits, random tomato scenario 1039 without obstacles) the position part of
    the learned field alone comes to rest 16.7 cm from the goal, and the arm circled 7-19 cm from
    it for 40 s. Evaluated at the reference, (p, ζ_r) is PUMA's own system driven through the
    hand's position, so the position goes on to the goal where the joints cannot give the
    orientation (7 of the 10 such evaluation runs reached it). Where the hand follows the
    reference, ζ = ζ_r at every step and this is PUMA's feedback law unchanged
    (tests/test_orientation_reference.py). Where obstacles hold the hand it is off: a
    reference running on PUMA's field while the barriers hold the hand's position took it off
    PUMA's own path (behind an obstacle far from the goal it turned the hand up to 3 rad away;
    beside one near the goal, Table-1 pouring 8 and 12, the hand went out and back, 13 s longer
    than with the feedback law). The saturation keeps an unreachable reference from driving the
    joints at k_p times a large error.
    k_p [1/s²], k_d [1/s]: tracking gains; max_acceleration a_max [rad/s²]; radius [m];
    clearance [m].
    """

    def __init__(self, stiffness: float = 16.0, damping: float = 8.0,
                 max_acceleration: float = np.inf, radius: float = np.inf,
                 clearance: float = 0.0, leash: float = np.inf):
        self.stiffness, self.damping = float(stiffness), float(damping)
        self.radius, self.clearance = float(radius), float(clearance)
        self.leash = float(leash)
        self.max_acceleration = float(max_acceleration)
        self.reset()

    def reset(self) -> None:
        self.quat = self.omega = self.alpha = None
        self.t = None
        self.active = False  # on: the primitive sees the reference (see sync)

    def sync(self, t: float, state: KinematicState, qd: np.ndarray,
             goal_position: np.ndarray, clearance: float = np.inf) -> None:
        """At an observation at time t [s]: off farther than ``radius`` [m] from the goal or
        with a body sphere closer than ``clearance`` [m] to an obstacle (clearance: the least
        one now, inf without obstacles); on otherwise, starting from the hand's (ζ, ω) when it
        comes on, else integrated over the elapsed time with the last α."""
        if (math.dist(state.ee_position, goal_position) > self.radius
                or clearance < self.clearance):
            self.active = False
        elif not self.active:
            self.quat = np.array(state.ee_quaternion, dtype=float)
            self.omega = state.ee_jacobian[3:] @ qd
            self.alpha = np.zeros(3)
            self.active = True
        elif t > self.t:
            dt = t - self.t
            self.omega = self.omega + dt * self.alpha
            q = quat_mul(quat_exp(self.omega * dt), self.quat)
            self.quat = q / np.linalg.norm(q)
            if np.isfinite(self.leash):
                self._hold_on_leash(np.asarray(state.ee_quaternion, dtype=float))
        self.t = t

    def _hold_on_leash(self, hand: np.ndarray) -> None:
        """Keep ζ_r within ``leash`` [rad] of the hand's ζ: beyond it ζ_r is moved back along
        the geodesic to the leash, and ω_r loses its component away from the hand."""
        err = quat_log(quat_mul(self.quat, quat_conj(hand)))  # ζ_r relative to ζ, rotation vector
        angle = float(np.linalg.norm(err))
        if angle <= self.leash:
            return
        u = err / angle
        self.quat = quat_mul(quat_exp(self.leash * u), hand)
        away = float(self.omega @ u)
        if away > 0.0:
            self.omega = self.omega - away * u

    def tracking(self, quat: np.ndarray, omega: np.ndarray, omega_r: np.ndarray
                 ) -> np.ndarray:
        """``sat(k_p log(ζ_r ζ⁻¹) + k_d (ω_r − ω))`` [rad/s²] (world frame) for the hand's
        (ζ, ω) and the reference's angular velocity ω_r (its own, or 0 for a what-if at rest)."""
        err = quat_log(quat_mul(self.quat, quat_conj(quat)))
        acc = self.stiffness * err + self.damping * (omega_r - omega)
        n = float(np.linalg.norm(acc))
        return acc if n <= self.max_acceleration else acc * (self.max_acceleration / n)


class PoseTask:
    """End-effector pose (position and orientation) task for a pose primitive; m = 6 rows
    [v; ω] of the world-aligned frame Jacobian. reference: an :class:`OrientationReference`
    the primitive sees instead of the hand's orientation where it is on (None: the hand's,
    PUMA's own law)."""

    def __init__(self, primitive, reference: OrientationReference | None = None):
        self.primitive = primitive
        self.reference = reference

    def acceleration(self, state: KinematicState, qd: np.ndarray, goal_position: np.ndarray,
                     goal_quaternion: np.ndarray,
                     goal_velocity: np.ndarray | None = None,
                     at_rest: bool = False) -> TaskAcceleration:
        """goal_velocity (3,) [m/s]: if given, the primitive sees the end effector's velocity
        relative to the (translating) goal, ``ṗ − v_g`` (its state is goal-relative).
        at_rest: with a reference, evaluate it at rest too (ω_r = 0; qd is then the caller's
        zeros) and do not keep this α for its next integration step (a what-if evaluation)."""
        twist = state.ee_jacobian @ qd
        v = twist[:3] if goal_velocity is None else twist[:3] - goal_velocity
        ref = self.reference
        if ref is None or not ref.active:
            a, alpha = self.primitive.acceleration(state.ee_position, state.ee_quaternion, v,
                                                   twist[3:], goal_position, goal_quaternion)
            return TaskAcceleration(np.concatenate([a, alpha]), state.ee_jacobian,
                                    state.ee_jdqd)
        omega_r = np.zeros(3) if at_rest else ref.omega
        a, alpha = self.primitive.acceleration(state.ee_position, ref.quat, v, omega_r,
                                               goal_position, goal_quaternion)
        alpha = np.asarray(alpha, dtype=float)
        if not at_rest:
            ref.alpha = alpha
        target = alpha + ref.tracking(state.ee_quaternion, twist[3:], omega_r)
        return TaskAcceleration(np.concatenate([a, target]), state.ee_jacobian, state.ee_jdqd)

    def potential(self, state: KinematicState, goal_position: np.ndarray,
                  goal_quaternion: np.ndarray) -> tuple[float, np.ndarray]:
        """ψ and ∂ψ/∂q = ∂ψ/∂p · J_v + ∂ψ/∂θ · J_ω (n,)."""
        psi, d_p, d_theta = self.primitive.potential(state.ee_position, state.ee_quaternion,
                                                     goal_position, goal_quaternion)
        jac = state.ee_jacobian
        return float(psi), d_p @ jac[:3] + d_theta @ jac[3:]

    def psi(self, state: KinematicState, goal_position: np.ndarray,
            goal_quaternion: np.ndarray) -> float:
        """ψ alone at the hand's pose (no gradient): for the log (a primitive without ``psi``:
        its :meth:`potential`)."""
        if not hasattr(self.primitive, "psi"):
            return self.potential(state, goal_position, goal_quaternion)[0]
        return self.primitive.psi(state.ee_position, state.ee_quaternion, goal_position,
                                  goal_quaternion)


class PlanarTask:
    """End-effector position in the plane (x, y) for an R² primitive (the point robot)."""

    def __init__(self, primitive, dims: int = 2):
        self.primitive = primitive
        self.dims = dims
        self.reference = None  # no orientation: PoseTask's reference has no counterpart here

    def acceleration(self, state: KinematicState, qd: np.ndarray, goal_position: np.ndarray,
                     goal_quaternion: np.ndarray, goal_velocity: np.ndarray | None = None,
                     at_rest: bool = False) -> TaskAcceleration:
        """As :meth:`PoseTask.acceleration` (at_rest: no state to keep, so no effect)."""
        d = self.dims
        J = state.ee_jacobian[:d]
        v = J @ qd if goal_velocity is None else J @ qd - goal_velocity[:d]
        xdd = self.primitive.acceleration(state.ee_position[:d], v, goal_position[:d])
        return TaskAcceleration(np.asarray(xdd, dtype=float), J, state.ee_jdqd[:d])

    def potential(self, state: KinematicState, goal_position: np.ndarray,
                  goal_quaternion: np.ndarray) -> tuple[float, np.ndarray]:
        d = self.dims
        psi, grad = self.primitive.potential(state.ee_position[:d], goal_position[:d])
        return float(psi), np.asarray(grad, dtype=float) @ state.ee_jacobian[:d]

    def psi(self, state: KinematicState, goal_position: np.ndarray,
            goal_quaternion: np.ndarray) -> float:
        """ψ alone at the hand's position (no gradient): for the log (a primitive without
        ``psi``: its :meth:`potential`)."""
        if not hasattr(self.primitive, "psi"):
            return self.potential(state, goal_position, goal_quaternion)[0]
        return self.primitive.psi(state.ee_position[:self.dims], goal_position[:self.dims])


def damped_pseudo_inverse(J: np.ndarray, damping: float) -> np.ndarray:
    """``J⁺ = Jᵀ (J Jᵀ + λ² I)⁻¹`` (n, m), by a linear solve; λ = damping."""
    G = J @ J.T
    G.flat[::J.shape[0] + 1] += damping**2  # + λ²I (the same numbers as adding λ² np.eye(m))
    return linear_solve(G, J).T


def manipulability(J: np.ndarray) -> float:
    """Yoshikawa's manipulability ``w = √det(J Jᵀ)`` of a (m, n) Jacobian (m ≤ n) [1]."""
    sign, logdet = np.linalg.slogdet(J @ J.T)
    return float(np.exp(0.5 * logdet)) if sign > 0 else 0.0


@dataclass(frozen=True)
class Damping:
    """Damping λ of the pseudo-inverse, growing as the manipulability w falls below w₀
    (Nakamura-Hanafusa / Chiaverini singularity-robust inverse):
    ``λ² = λ₀² + λ_max² (1 − w/w₀)²`` for w < w₀, else λ₀². lam_max = 0: constant λ₀."""

    lam0: float = 0.01
    lam_max: float = 0.0
    w0: float = 0.02

    def __call__(self, J: np.ndarray) -> float:
        if self.lam_max <= 0.0:
            return self.lam0
        w = manipulability(J)
        if w >= self.w0:
            return self.lam0
        return float(np.sqrt(self.lam0**2 + (self.lam_max * (1.0 - w / self.w0)) ** 2))


def pull_to_joints(task: TaskAcceleration, damping: float | Damping,
                   qdd_null: np.ndarray | None = None) -> np.ndarray:
    """``q̈ = J⁺(ẍ_d − J̇q̇) + (I − J⁺J) q̈_null`` [rad/s²]; damping: λ, or a :class:`Damping`
    rule evaluated at J."""
    if callable(damping):
        damping = damping(task.J)
    pinv = damped_pseudo_inverse(task.J, damping)
    qdd = pinv @ (task.xdd - task.jdqd)
    if qdd_null is not None:
        qdd = qdd + qdd_null - pinv @ (task.J @ qdd_null)
    return qdd


def weighted_rows(weight: float | np.ndarray, J: np.ndarray) -> np.ndarray:
    """diag(w) J (m, n): J's rows times the task metric w, a scalar or one weight per row (m,).
    A scalar multiplies as it is (the same numbers as broadcasting it as (1, 1))."""
    return weight * J if type(weight) is float else np.multiply(np.reshape(weight, (-1, 1)), J)


def pull_through_metric(task: TaskAcceleration, W: np.ndarray, weight: float | np.ndarray,
                        m_null: float, qdd_null: np.ndarray | None = None,
                        extra=None, priority: int = 0,
                        secondary: SecondaryDamping | None = None) -> np.ndarray:
    """PUMA's task acceleration pulled to the joints through a metric (a weighted
    pseudo-inverse): the task spec ``(w I, −w ẍ_d)`` pulled back and summed with a joint-space
    spec ``(W, 0)`` and the secondary objective's ``(m_null I, −m_null q̈_null)``::

        q̈_C = (W + w JᵀJ + m_null I)⁻¹ (w Jᵀ(ẍ_d − J̇q̇) + m_null q̈_null)        [rad/s²]

    W (n, n) SPD [1]; w [1], or one weight per task row (m,) (the task metric diag(w), e.g.
    position rows before orientation rows: :meth:`~tamedpuma.methods._tamed.Forcing.task_weights`);
    m_null [1]. Where W ≪ w JᵀJ q̈_C realises ẍ_d as the damped
    least-squares inverse with λ² = W/w does (W = m_b I: exactly that); along a direction in
    which W is large (an obstacle barrier's metric) q̈_C's component falls like 1/W. At ẍ_d = 0
    and q̇ = 0 (PUMA's zero set) q̈_C = (…)⁻¹ m_null q̈_null, the damped elbow attractor.
    extra: more acceleration specs summed in, rows R (K, n) with targets a and weights w_k (a
    :class:`~tamedpuma.methods._circulation.TangentSpecs`): ``+ Σ w_k R_kᵀR_k`` in the metric,
    ``+ Σ w_k R_kᵀ a_k`` on the right.
    priority: the first ``priority`` task rows (J₁, the position rows of a pose task) take
    precedence over the rest (J₂): see :func:`prioritized_solve`. 0: one weighted solve.
    secondary: the singularity-robust damping of the rest (J₂) under a priority
    (:class:`SecondaryDamping`; None: none)."""
    J = task.J
    m = J.shape[0]
    k = priority if priority > 0 else m
    wJ = weighted_rows(weight, J)
    target = task.xdd - task.jdqd
    J1, wJ1 = (J, wJ) if k == m else (J[:k], wJ[:k])  # (views of all rows: the same numbers)
    A = W + J1.T @ wJ1
    rhs = wJ1.T @ (target if k == m else target[:k])
    if qdd_null is not None and m_null > 0.0:
        A.flat[::A.shape[0] + 1] += m_null  # A is a fresh array
        rhs = rhs + m_null * qdd_null
    if extra is not None:
        wr = extra.weights[:, None] * extra.rows
        A += extra.rows.T @ wr
        rhs = rhs + wr.T @ extra.targets
    if k == m:
        return linear_solve(A, rhs)
    A2 = J[k:].T @ wJ[k:]
    D = None if secondary is None else secondary.metric(
        A, J1, A2, m - k, weighted_rows(math.sqrt(weight) if type(weight) is float
                                        else np.sqrt(np.asarray(weight)[k:]), J[k:]))
    if D is not None:
        A2 = A2 + D
    return prioritized_solve(A, rhs, J1, A2, wJ[k:].T @ target[k:])


@dataclass(frozen=True)
class SecondaryDamping:
    """Singularity-robust damping of the secondary (orientation) rows of a prioritized pullback
    (μ_max [1], σ₀ [1]; with ``method.forcing.priority: position``; Chiaverini
    1997's singularity-robust task priority, in the metric of the first stage).

    The second stage of :func:`prioritized_solve` minimises ``½q̈ᵀ(A₁ + A₂)q̈ − (f₁ + f₂)ᵀq̈``
    under the position constraint, A₁ = LLᵀ the first stage's metric (the avoidance metric, the
    position rows' wJ₁ᵀJ₁, the elbow objective's), A₂ = J₂ᵀdiag(w)J₂. In u = Lᵀq̈ the secondary
    rows are ``Ĵ₂ = diag(√w) J₂ L⁻ᵀ`` and the position constraint fixes u's component in
    the row space of ``Ĵ₁ = J₁L⁻ᵀ``; what is left to the secondary rows is ``Ĵ₂N₁``, N₁ the
    orthogonal projector onto Ĵ₁'s null space, with singular values σ̂ᵢ (σ̂ᵢ² the eigenvalues
    of N₁L⁻¹A₂L⁻ᵀN₁, at most m₂ non-zero) and right singular vectors vᵢ ∈ range(N₁): the
    target's share along vᵢ is realised as the fraction σ̂ᵢ²/(σ̂ᵢ² + 1), with a joint
    acceleration per unit of target ∝ σ̂ᵢ/(σ̂ᵢ² + 1), largest at σ̂ᵢ = 1: where the joints that
    could turn the hand are held by barrier metrics or at a singularity of their own (the wrist
    at q₆ ≈ 0), the orientation rows drive the rest hard. Each direction with σ̂ᵢ < σ₀ gets the
    extra metric

        D = Σ_{σ̂ᵢ<σ₀} μᵢ (Lvᵢ)(Lvᵢ)ᵀ,   μᵢ = μ_max (1 − σ̂ᵢ/σ₀)²                  [1]

    in the second stage only (gain σ̂ᵢ/(σ̂ᵢ² + 1 + μᵢ)); directions at or above σ₀ and the
    position rows' acceleration J₁q̈ = J₁q̈₁ are unchanged (vᵢ ⊥ Ĵ₁'s rows: damping them never
    shifts the position rows onto other joints, which the unprojected σ̂ of Ĵ₂ did, raising ‖q̈‖
    up to 5× at random wrist-singular states). With the first rows asking nothing (f₁ = 0,
    undamped constraint) the orientation's share is exactly ``vᵢ·Lᵀq̈ = vᵢ·L⁻¹f₂/(1 + σ̂ᵢ² +
    μᵢ)``. D is PSD and depends only on the configuration and the metrics, so q̈_C is still a
    weighted pseudo-inverse of PUMA's spec through a PSD metric: at ẍ_d = 0 and q̇ = 0 it is
    the damped elbow objective (with more damping along the vᵢ), 0 without one, so the zero set
    of the forcing and the statements resting on it are unchanged.

    Why: the default tomato scenario (shipped models), FPM: at 6.5-7.0 s the orientation rows
    asked 1.4-4 rad/s² with σ̂_min 0.2-1 (the wrist through q₆ ≈ 0, joints 1-3 held by obstacle
    metrics of 130-480), q̈_C reached 14 rad/s², joints 5 and 7 spun at 2.2 rad/s in opposite
    directions, joint 7 ran into its limit and the hand swung out to 0.85 m from the goal"""

    gain: float = 0.0
    threshold: float = 3.0

    def metric(self, A1: np.ndarray, J1: np.ndarray, A2: np.ndarray,
               rank: int, rows2: np.ndarray | None = None) -> np.ndarray | None:
        """D (n, n) [1] for the first stage's metric A₁ (SPD), the first rows J₁ (k, n) and the
        secondary rows' A₂ (PSD, rank ≤ ``rank``); None (nothing to add: the common case in
        free space) when no direction is below σ₀ or μ_max = 0.

        rows2: a factor of A₂ (``A₂ = rows2ᵀ rows2``, i.e. diag(√w) J₂, (m₂, n)), when known:
        where the small (m₂, m₂) problem of :meth:`_small` finds every σ̂ᵢ clearly (10⁻⁶
        relative) above σ₀, None without the (n, n) eigenproblem; otherwise D from it, the
        same numbers as without rows2."""
        n = A1.shape[0]
        if self.gain <= 0.0 or rank <= 0:
            return None
        L = np.linalg.cholesky(A1)
        if rows2 is not None and self._clearly_above(L, J1, rows2):
            return None
        X = np.linalg.solve(L, np.linalg.solve(L, A2).T)  # L⁻¹A₂L⁻ᵀ (A₂ symmetric)
        J1u = np.linalg.solve(L, J1.T).T  # J₁L⁻ᵀ: the first rows in u
        try:
            N1 = np.eye(n) - J1u.T @ np.linalg.solve(J1u @ J1u.T, J1u)
        except np.linalg.LinAlgError:  # the position rows singular (e.g. the arm straight up)
            N1 = np.eye(n) - np.linalg.pinv(J1u) @ J1u
        lam, V = np.linalg.eigh(N1 @ (0.5 * (X + X.T)) @ N1)
        lam = lam[-rank:]
        sigma = np.sqrt(np.maximum(lam, 0.0))
        # only directions the secondary rows reach (σ̂ > 0): an eigenvector of a zero eigenvalue
        # may lie along the position rows (where the whole Jacobian is singular)
        low = (sigma < self.threshold) & (lam > 1e-12 * max(float(lam[-1]), 1.0))
        if not low.any():
            return None
        mu = self.gain * (1.0 - sigma[low] / self.threshold) ** 2
        LV = L @ V[:, -rank:][:, low]
        return (LV * mu) @ LV.T

    def _clearly_above(self, L: np.ndarray, J1: np.ndarray, rows2: np.ndarray) -> bool:
        """Whether every σ̂ᵢ is above σ₀ by 10⁻⁶ relative (far beyond the rounding in which the
        two problems differ). With Ĵ₁ᵀ = L⁻¹J₁ᵀ and Ĵ₂ᵀ = L⁻¹rows2ᵀ, ``G = Ĵ₂N₁Ĵ₂ᵀ =
        Ĵ₂Ĵ₂ᵀ − Ĵ₂Ĵ₁ᵀ(Ĵ₁Ĵ₁ᵀ)⁻¹Ĵ₁Ĵ₂ᵀ`` has the non-zero eigenvalues σ̂ᵢ² of ``N₁L⁻¹A₂L⁻ᵀN₁``
        (N₁ a projector)."""
        k = J1.shape[0]
        Y = np.linalg.solve(L, np.concatenate((J1, rows2)).T)  # [Ĵ₁ᵀ, Ĵ₂ᵀ]
        Y1, Y2 = Y[:, :k], Y[:, k:]
        C = Y1.T @ Y2
        try:
            G = Y2.T @ Y2 - C.T @ np.linalg.solve(Y1.T @ Y1, C)
        except np.linalg.LinAlgError:  # the position rows singular: the (n, n) problem decides
            return False
        lam = np.linalg.eigvalsh(0.5 * (G + G.T))
        return bool(lam[0] >= (self.threshold * (1.0 + 1e-6)) ** 2)


#: δ [1] of :func:`prioritized_solve`: the priority constraint's damping relative to tr(S)/k
PRIORITY_DAMPING = 1e-2


def prioritized_solve(A1: np.ndarray, f1: np.ndarray, J1: np.ndarray, A2: np.ndarray,
                      f2: np.ndarray) -> np.ndarray:
    """Two specs solved in order [rad/s²]: first ``q̈₁ = A₁⁻¹f₁`` (the high-priority spec alone:
    PUMA's position rows with the avoidance metric and the rest), then the low-priority spec
    (A₂, f₂) (the orientation rows, ``wJ₂ᵀJ₂`` and ``wJ₂ᵀ(ẍ₂ − J̇₂q̇)``) added without changing
    the high-priority task acceleration J₁q̈₁: the minimiser of
    ``½q̈ᵀ(A₁ + A₂)q̈ − (f₁ + f₂)ᵀq̈`` subject to ``J₁q̈ = J₁q̈₁`` (a lexicographic least-squares
    solve, as in task-priority control, Nakamura et al. 1987; Siciliano & Slotine 1991)::

        q̈ = A⁻¹(f₁ + f₂ − J₁ᵀλ),  λ = (J₁A⁻¹J₁ᵀ)⁻¹(J₁A⁻¹(f₁ + f₂) − J₁q̈₁),  A = A₁ + A₂

    A₁ (n, n) SPD [1]; f₁, f₂ (n,); J₁ (k, n); A₂ (n, n) PSD [1].

    Why (``forcing.priority: position``). With one weighted solve, where barriers hold joints
    (two joints at their limit barriers leave 5 for PUMA's 6 pose rows) the arm comes to rest
    wherever the position and orientation pulls cancel in the free joints, short of the goal
    (the stall of the online goal change and of random starts at the joint limits). Here the
    hand's acceleration is the one PUMA's position pull alone would give,
    ``J₁q̈ = J₁A₁⁻¹J₁ᵀ w ẍ₁`` at rest, positive definite while the free joints span the
    position rows: the hand moves along PUMA's position pull until ẍ₁ = 0 or an obstacle's
    metric takes that direction away; the orientation uses the joints left over. In free space
    (7 joints for 6 rows, small metric) both specs are met, as with one solve. ẍ_d = 0 gives
    f₁ = f₂ = 0 besides the elbow objective in f₁: the zero set of the forcing, hence FPM's and
    CPM's statements, are unchanged. S = J₁A⁻¹J₁ᵀ is damped by δ tr(S)/k,
    δ = :data:`PRIORITY_DAMPING` (a singularity-robust task priority, Chiaverini 1997): where S
    is ill-conditioned the constraint yields instead of driving the joints (with δ = 10⁻⁹, near
    the shoulder singularity q₂ ≈ 0 the multiplier swung joints 1 and 3 through 2 rad in 2 s
    and the hand left the goal by 1.4 m; random tomato scenario 103)."""
    n, k = J1.shape[1], J1.shape[0]
    qdd1 = linear_solve(A1, f1)
    B = np.empty((n, k + 1))  # [J₁ᵀ, f₁ + f₂]
    B[:, :k] = J1.T
    np.add(f1, f2, out=B[:, k])
    X = linear_solve(A1 + A2, B)
    AJ = X[:, :k]  # A⁻¹J₁ᵀ
    S = J1 @ AJ
    S.flat[::k + 1] += PRIORITY_DAMPING * max(float(S.trace()), 1e-300) / k
    x = X[:, k]
    return x - AJ @ linear_solve(S, J1 @ (x - qdd1))


@dataclass(frozen=True)
class NullSpaceObjective:
    """Secondary "elbow up" objective: attract a link origin to a point [m]:
    ``q̈_null = k J_linkᵀ (p* − p_link) − d q̇`` (stiffness k [1/s²], damping d [1/s])."""

    link: str
    target: tuple[float, float, float]
    stiffness: float
    damping: float

    def acceleration(self, kinematics, qd: np.ndarray) -> np.ndarray:
        p, J = kinematics.link_position_jacobian(self.link)
        return self.stiffness * J.T @ (np.asarray(self.target) - p) - self.damping * qd


class LinearTaskPrimitive:
    """Analytic stand-in for a trained R^d primitive (tests, examples): the critically damped
    ``ẍ = −k (x − x_g) − d ẋ`` with the compatible potential ``ψ = ‖x − x_g‖²``."""

    def __init__(self, stiffness: float = 1.0, damping: float = 2.0):
        self.stiffness, self.damping = stiffness, damping

    def acceleration(self, x, xd, goal):
        return -self.stiffness * (np.asarray(x) - goal) - self.damping * np.asarray(xd)

    def potential(self, x, goal):
        e = np.asarray(x) - goal
        return float(e @ e), 2.0 * e
