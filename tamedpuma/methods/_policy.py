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

from dataclasses import dataclass, field

import numpy as np

from tamedpuma.fabrics.spec import linear_solve
from tamedpuma.methods._kernels import STEP
from tamedpuma.robot.kinematics import KinematicState


def episode_primitive(primitive):
    """The primitive one episode evaluates: a trained one's wrapper for the episode
    (``for_episode``: the network shared, the one-state buffers and the rest-row memo its own,
    :mod:`tamedpuma.puma.single`), so a step writes the network's buffers only in the episode
    state; a primitive without buffers (an analytic stand-in) itself."""
    own = getattr(primitive, "for_episode", None)
    return primitive if own is None else own()


@dataclass(frozen=True)
class TaskAcceleration:
    """xdd (m,) desired task acceleration; J (m, n) task Jacobian; jdqd (m,) = J̇q̇."""

    xdd: np.ndarray
    J: np.ndarray
    jdqd: np.ndarray


class PoseTask:
    """End-effector pose (position and orientation) task for a pose primitive; m = 6 rows
    [v; ω] of the world-aligned frame Jacobian."""

    def __init__(self, primitive):
        self.primitive = primitive

    def acceleration(self, state: KinematicState, qd: np.ndarray, goal_position: np.ndarray,
                     goal_quaternion: np.ndarray,
                     goal_velocity: np.ndarray | None = None) -> TaskAcceleration:
        """goal_velocity (3,) [m/s]: if given, the primitive sees the end effector's velocity
        relative to the (translating) goal, ``ṗ − v_g`` (its state is goal-relative)."""
        twist = state.ee_jacobian @ qd
        v = twist[:3] if goal_velocity is None else twist[:3] - goal_velocity
        prim, xdd = self.primitive, None
        one = getattr(prim, "single", None)  # a trained primitive's one-state evaluator
        if one is not None:  # [a; α] in one compiled call from the packed state, where it applies
            xdd = one.forward_packed(np.concatenate((state.ee_position, state.ee_quaternion,
                                                     goal_position, goal_quaternion, v,
                                                     twist[3:])))
        if xdd is None:
            xdd = np.concatenate(prim.acceleration(state.ee_position, state.ee_quaternion, v,
                                                   twist[3:], goal_position, goal_quaternion))
        return TaskAcceleration(xdd, state.ee_jacobian, state.ee_jdqd)

    def potential(self, state: KinematicState, goal_position: np.ndarray,
                  goal_quaternion: np.ndarray) -> tuple[float, np.ndarray]:
        """ψ and ∂ψ/∂q = ∂ψ/∂p · J_v + ∂ψ/∂θ · J_ω (n,)."""
        prim, jac = self.primitive, state.ee_jacobian
        one = getattr(prim, "single", None)  # a trained primitive's one-state evaluator
        if one is not None:  # ψ and its pull in one compiled call, where it applies
            out = one.potential_packed(np.concatenate((state.ee_position, state.ee_quaternion,
                                                       goal_position, goal_quaternion)), jac)
            if out is not None:
                return out
        psi, d_p, d_theta = prim.potential(state.ee_position, state.ee_quaternion,
                                           goal_position, goal_quaternion)
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

    def acceleration(self, state: KinematicState, qd: np.ndarray, goal_position: np.ndarray,
                     goal_quaternion: np.ndarray, goal_velocity: np.ndarray | None = None
                     ) -> TaskAcceleration:
        """As :meth:`PoseTask.acceleration`."""
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
                        m_null: float, qdd_null: np.ndarray | None = None) -> np.ndarray:
    """PUMA's task acceleration pulled to the joints through a metric (a weighted
    pseudo-inverse): the task spec ``(w I, −w ẍ_d)`` pulled back and summed with a joint-space
    spec ``(W, 0)`` and the secondary objective's ``(m_null I, −m_null q̈_null)``::

        q̈_C = (W + w JᵀJ + m_null I)⁻¹ (w Jᵀ(ẍ_d − J̇q̇) + m_null q̈_null)        [rad/s²]

    W (n, n) SPD [1]; w [1], or one weight per task row (m,) (the task metric diag(w));
    m_null [1]. Where W ≪ w JᵀJ q̈_C realises ẍ_d as the damped
    least-squares inverse with λ² = W/w does (W = m_b I: exactly that); along a direction in
    which W is large (an obstacle barrier's metric) q̈_C's component falls like 1/W. At ẍ_d = 0
    and q̇ = 0 (PUMA's zero set) q̈_C = (…)⁻¹ m_null q̈_null, the damped elbow attractor."""
    J = task.J
    wJ = weighted_rows(weight, J)
    A = W + J.T @ wJ
    rhs = wJ.T @ (task.xdd - task.jdqd)
    if qdd_null is not None and m_null > 0.0:
        A.flat[::A.shape[0] + 1] += m_null  # A is a fresh array
        rhs = rhs + m_null * qdd_null
    return linear_solve(A, rhs)


@dataclass(frozen=True)
class NullSpaceObjective:
    """Secondary "elbow up" objective: attract a link origin to a point [m]:
    ``q̈_null = k J_linkᵀ (p* − p_link) − d q̇`` (stiffness k [1/s²], damping d [1/s])."""

    link: str
    target: tuple[float, float, float]
    stiffness: float
    damping: float
    target_array: np.ndarray = field(init=False, repr=False, compare=False)  # p* (3,) [m]

    def __post_init__(self):
        object.__setattr__(self, "target_array", np.array(self.target, dtype=float))

    def acceleration(self, kinematics, qd: np.ndarray) -> np.ndarray:
        chain_of = getattr(kinematics, "link_chain_state", None)
        chain = chain_of(self.link) if chain_of and STEP["null_pull"].fast else None
        if chain is not None:  # the link's motion and the pull in one compiled call
            return STEP["null_pull"](*chain, self.target_array, float(self.stiffness),
                                     float(self.damping), qd)
        p, J = kinematics.link_position_jacobian(self.link)
        return self.stiffness * J.T @ (self.target_array - p) - self.damping * qd


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
