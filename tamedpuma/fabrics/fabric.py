"""The assembled joint-space fabric: avoidance leaves, goal forcing, energization and speed control.

:class:`Fabric` holds only gains and robot limits; nothing depends on the obstacle count, which is
run-time data of every call (no build step, nothing rebuilt when it changes). Per call:

1. avoidance (the unforced fabric, method.md §2): base ``(m_b I, 0)`` plus the pullback of every
   barrier leaf spec ``(M_L, M_L h)`` (body sphere × obstacle pairs, joint limits, optional ground)
   ⇒ ``(M, f)`` in joint space, together with the pulled energy force f_L and energy ``H_{L_e}``
   (``M`` is also the pulled energy metric, since each leaf is weighted by its energy's metric);
2. forcing: the goal attractor's spec ``(g I, g ∇ψ)`` pulled back from the position and orientation
   errors ⇒ ``(M_ψ, f_ψ)``;
3. ``q̈_G = −M⁻¹ f`` and ``q̈_F = −(M + M_ψ)⁻¹ (f + f_ψ)`` in one batched solve;
4. speed control (:mod:`tamedpuma.fabrics.speed`): ``q̈ = q̈_F − (α_ex + β) q̇``.

TamedPUMA's FPM and CPM reuse step 1 (:meth:`Fabric.avoidance`),
:meth:`AvoidanceFabric.acceleration` and :func:`tamedpuma.fabrics.energy.energize` /
:meth:`AvoidanceFabric.alpha`.
numpy only.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from tamedpuma.fabrics.energy import BarrierBatch, attractor_blocks, barrier_batch
from tamedpuma.fabrics.gains import FabricGains
from tamedpuma.fabrics.leaves import (
    goal_errors,
    ground_plane,
    pull_sphere_pairs,
    sphere_obstacle_pairs,
)
from tamedpuma.fabrics.spec import FabricError, Spec, solve_acceleration
from tamedpuma.fabrics.speed import speed_terms


@dataclass(slots=True)
class AvoidanceFabric:
    """The unforced fabric in joint space, ``M q̈ + f = 0`` (a result: treat as read-only).

    M (n, n) SPD metric (= pulled energy metric, incl. base); forces (2, n): rows f (the geometry
    force) and f_energy (the pulled force of the fabric energy L_e); energy: ``H_{L_e}``;
    min_clearance [m]: smallest ``‖c_i − o_j‖ − r_i − r_j`` (inf without obstacles);
    ground_clearance [m] (inf when the ground leaf is off); n_clamped: barrier distances clamped
    to the margin (obstacle/ground pairs); n_limit_clamped: joint-limit distances clamped.
    """

    M: np.ndarray
    forces: np.ndarray
    energy: float
    min_clearance: float
    ground_clearance: float
    n_clamped: int
    n_limit_clamped: int

    @property
    def f(self) -> np.ndarray:
        """Geometry force f (n,): ``M q̈ + f = 0`` is the unforced fabric."""
        return self.forces[0]

    @property
    def f_energy(self) -> np.ndarray:
        """Pulled force f_L (n,) of the fabric energy (for energization)."""
        return self.forces[1]

    @property
    def spec(self) -> Spec:
        return Spec(self.M, self.f)

    def acceleration(self) -> np.ndarray:
        """Geometry acceleration ``q̈_G = −M⁻¹ f`` [rad/s²] (linear solve)."""
        return solve_acceleration(self.M, self.f)

    def alpha(self, qd, qdd, eps: float = 1e-6) -> float:
        """Energization coefficient of ``q̈ = qdd`` w.r.t. the fabric energy L_e:
        ``α = q̇ᵀ(M q̈ + f_L)/(q̇ᵀ M q̇ + ε)`` [1/s]; then ``qdd − α q̇`` conserves ``H_{L_e}``."""
        Mqd = self.M @ qd
        return float((Mqd @ qdd + qd @ self.f_energy) / (qd @ Mqd + eps))


@dataclass(slots=True)
class Forcing:
    """The goal attractor pulled back: ``(M_ψ, f_ψ)`` (n, n), (n,); potential ψ [m²/s²];
    goal_distance ‖p_ee − p_g‖ [m]; orientation_error: Σ_k ‖R_ee a_k − R_g a_k‖ [m]."""

    M: np.ndarray
    f: np.ndarray
    potential: float
    goal_distance: float
    orientation_error: float


@dataclass(slots=True)
class FabricDiagnostics:
    """Scalars of one evaluation, for the log.

    energy_fabric: ``H_{L_e}`` (sum of the leaves' and the base energies, each in its task
    variable's units²/s²); energy_execution ``‖q̇‖²`` [rad²/s²]; potential ψ [m²/s²]; α's and β
    [1/s]; η [1]; clearances and distances [m]; n_clamped, n_limit_clamped: counts.
    """

    energy_fabric: float
    energy_execution: float
    potential: float
    alpha_geometry: float
    alpha_0: float
    alpha_psi: float
    alpha_ex: float
    eta: float
    beta: float
    min_clearance: float
    ground_clearance: float
    n_clamped: int
    n_limit_clamped: int
    goal_distance: float
    orientation_error: float

    def as_scalars(self) -> dict[str, float]:
        return {k: float(v) for k, v in asdict(self).items()}


def quaternion_to_rotation(quat) -> np.ndarray:
    """Rotation matrix (3, 3) of a quaternion (x, y, z, w) (normalised first)."""
    x, y, z, w = np.asarray(quat, dtype=float) / np.linalg.norm(quat)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


class Fabric:
    """Geometric fabric of one robot (see the module docstring).

    gains: :class:`FabricGains`; q_min, q_max: (n,) joint limits [rad].
    """

    def __init__(self, gains: FabricGains, q_min, q_max):
        self.gains = gains
        self.q_min = np.array(q_min, dtype=float)
        self.q_max = np.array(q_max, dtype=float)
        n = self._n = self.q_min.shape[0]
        self._base = gains.base_metric * np.eye(n)
        axes = list(gains.orientation_axes) if gains.orientation_weight > 0 else []
        self._offsets = gains.orientation_offset * np.eye(3)[axes]
        self._weight_list = [gains.goal_weight] + [gains.orientation_weight] * len(axes)
        self._batches: dict[tuple[int, int], BarrierBatch] = {}  # per (spheres, obstacles)

    def avoidance(self, state, q, qd, obstacle_centers, obstacle_radii,
                  obstacle_velocities) -> AvoidanceFabric:
        """The unforced fabric at (q, q̇) among the obstacles (see :class:`AvoidanceFabric`).

        state: a KinematicState at (q, q̇) (body spheres used); q, qd (n,) [rad], [rad/s];
        obstacle_centers (m, 3) [m], obstacle_radii (m,) [m], obstacle_velocities (m, 3) [m/s].
        """
        g = self.gains
        J = state.sphere_jacobians
        pairs = sphere_obstacle_pairs(state.sphere_centers, J, state.sphere_jdqd,
                                      state.sphere_radii, qd, obstacle_centers, obstacle_radii,
                                      obstacle_velocities, g.barrier_margin)
        k, n_obs = pairs.x.shape
        P = k * n_obs
        n = self._n
        L = P + 2 * n  # pairs, then lower and upper joint limits, then (optional) ground
        size = L + (k if g.ground_enabled else 0)
        # All barrier leaves in one batch: x and ẋ of every pair, limit and ground distance.
        X = np.empty((2, size))
        x, xd = X
        x[:P] = pairs.x.reshape(-1)
        xd[:P] = pairs.xd.reshape(-1)
        np.subtract(q, self.q_min, out=x[P:P + n])
        np.subtract(self.q_max, q, out=x[P + n:L])
        xd[P:P + n] = qd
        np.negative(qd, out=xd[P + n:L])
        n_limit_clamped = 0
        if x[P:L].min() < g.barrier_margin:
            n_limit_clamped = int(np.count_nonzero(x[P:L] < g.barrier_margin))
            np.maximum(x[P:L], g.barrier_margin, out=x[P:L])
        n_clamped = pairs.n_clamped
        ground_clearance = np.inf
        if g.ground_enabled:
            gr = ground_plane(state.sphere_centers, J, state.sphere_jdqd, state.sphere_radii, qd,
                              g.ground_height, g.barrier_margin)
            x[L:] = gr.x
            xd[L:] = gr.xd
            n_clamped += gr.n_clamped
            ground_clearance = float(gr.clearance.min())
        batch = self._batches.get((k, n_obs))
        if batch is None:  # per-element gains of this layout (cheap; no geometry is built)
            if len(self._batches) > 64:
                self._batches.clear()
            parts = [(g.obstacle, P), (g.joint_limit, 2 * n)]
            if g.ground_enabled:
                parts.append((g.ground, k))
            batch = self._batches[(k, n_obs)] = BarrierBatch.of(parts)
        m, f, f_l, h = barrier_batch(x, xd, batch)
        # pairs: pulled through the sphere Jacobians, aggregated per sphere
        mp = m[:P].reshape(k, n_obs)
        mj = mp * pairs.jdqd
        M, F = pull_sphere_pairs(mp, f[:P].reshape(k, n_obs) + mj,
                                 f_l[:P].reshape(k, n_obs) + mj, pairs.u, J)
        # joint limits: Jacobian rows +e_j (lower) and −e_j (upper), J̇q̇ = 0
        M += self._base
        M.reshape(-1)[:: n + 1] += m[P:P + n] + m[P + n:L]
        F[0] += f[P:P + n] - f[P + n:L]
        F[1] += f_l[P:P + n] - f_l[P + n:L]
        if g.ground_enabled:
            mg = m[L:]
            mgj = mg * gr.jdqd
            M += gr.rows.T @ (mg[:, None] * gr.rows)
            F[0] += (f[L:] + mgj) @ gr.rows
            F[1] += (f_l[L:] + mgj) @ gr.rows
        energy = float(h.sum()) + 0.5 * g.base_metric * float(qd @ qd)
        clearance = float(pairs.clearance.min()) if P else np.inf
        return AvoidanceFabric(M=M, forces=F, energy=energy,
                               min_clearance=clearance, ground_clearance=ground_clearance,
                               n_clamped=n_clamped, n_limit_clamped=n_limit_clamped)

    def forcing(self, state, qd, goal_position, goal_rotation) -> Forcing:
        """The goal attractor pulled into joint space (see :class:`Forcing`).

        goal_position (3,) [m]; goal_rotation (3, 3) (goal frame in the world).
        """
        g = self.gains
        terms = goal_errors(state.ee_position, state.ee_rotation, state.ee_jacobian,
                            state.ee_jdqd, qd, goal_position, goal_rotation, self._offsets)
        e = terms.e
        psi, r, ratio, gm = attractor_blocks(np.einsum("kd,kd->k", e, e).tolist(), g,
                                             self._weight_list)
        jac = terms.jacobians  # (K, 3, n + 1): [J | J̇q̇] per block
        jac[:, :, -1] += np.array(ratio)[:, None] * e  # → [J | J̇q̇ + ∇ψ]
        Jx = jac.reshape(-1, jac.shape[2])
        MM = Jx.T @ (jac * np.array(gm)[:, None, None]).reshape(Jx.shape)
        # MM = [[Σ g JᵀJ, Σ g Jᵀ(J̇q̇ + ∇ψ)], …] = [[M_ψ, f_ψ], …]
        return Forcing(M=MM[:-1, :-1], f=MM[:-1, -1], potential=psi,
                       goal_distance=r[0], orientation_error=sum(r[1:]))

    def evaluate(self, state, q, qd, obstacle_centers, obstacle_radii, obstacle_velocities,
                 goal_position, goal_rotation) -> tuple[np.ndarray, FabricDiagnostics]:
        """The vanilla Fabrics acceleration q̈ [rad/s²] at (q, q̇) and its diagnostics.

        Arguments as :meth:`avoidance` and :meth:`forcing`. Raises :class:`FabricError` on
        non-finite input or output (never a silent zero acceleration).
        """
        g = self.gains
        av = self.avoidance(state, q, qd, obstacle_centers, obstacle_radii, obstacle_velocities)
        fo = self.forcing(state, qd, goal_position, goal_rotation)
        n = self._n
        Ms = np.empty((2, n, n))
        rhs = np.empty((2, n))
        Ms[0] = av.M
        np.add(av.M, fo.M, out=Ms[1])
        rhs[0] = av.forces[0]
        np.add(rhs[0], fo.f, out=rhs[1])
        # q̈_G = −M⁻¹f and q̈_F = −(M + M_ψ)⁻¹(f + f_ψ) in one batched solve
        sol = solve_acceleration(Ms, rhs)
        # dot products with q̇: q̇ᵀf, q̇ᵀf_L, q̇ᵀq̈_G, q̇ᵀq̈_F, q̇ᵀMq̇, ‖q̇‖²
        qf, qfl = (av.forces @ qd).tolist()
        qg, qF = (sol @ qd).tolist()
        qMq = float((av.M @ qd) @ qd)
        speed_sq = float(qd @ qd)
        # α_G = q̇ᵀ(M q̈_G + f_L)/(q̇ᵀMq̇ + ε) = q̇ᵀ(f_L − f)/(q̇ᵀMq̇ + ε), since M q̈_G = −f.
        alpha_g = (qfl - qf) / (qMq + g.energization_eps)
        sp = speed_terms(speed_sq, qg, qF, alpha_g, fo.goal_distance, g)
        qdd = sol[1] - (sp.alpha_ex + sp.beta) * qd
        if not np.isfinite(qdd).all():
            raise FabricError("fabric acceleration is not finite (non-finite input?)")
        diag = FabricDiagnostics(
            energy_fabric=av.energy, energy_execution=speed_sq, potential=fo.potential,
            alpha_geometry=alpha_g, alpha_0=sp.alpha_0, alpha_psi=sp.alpha_psi,
            alpha_ex=sp.alpha_ex, eta=sp.eta, beta=sp.beta, min_clearance=av.min_clearance,
            ground_clearance=av.ground_clearance, n_clamped=av.n_clamped,
            n_limit_clamped=av.n_limit_clamped, goal_distance=fo.goal_distance,
            orientation_error=fo.orientation_error)
        return qdd, diag
