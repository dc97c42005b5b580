"""The assembled joint-space fabric: avoidance leaves, goal forcing, energization and speed control.

:class:`Fabric` holds only gains and robot limits, and no call writes it; nothing depends on the
obstacle count, which is run-time data of every call (no build step, nothing rebuilt when it
changes). The work buffers a call fills are the caller's, a :class:`FabricBuffers` (one
:class:`~tamedpuma.fabrics.fused.LayoutBuffers` per (spheres, obstacles) layout, allocated on
first use in well under a millisecond): a controller keeps one in its episode state. Per call:

1. avoidance (the unforced fabric, method.md §2): base ``(m_b I, 0)`` plus the pullback of every
   barrier leaf spec ``(M_L, M_L h)`` (body sphere × obstacle pairs, joint limits, optional ground)
   ⇒ ``(M, f)`` in joint space, together with the pulled energy force f_L and energy ``H_{L_e}``
   (``M`` is also the pulled energy metric, since each leaf is weighted by its energy's metric);
2. forcing: the goal attractor's spec ``(g I, g ∇ψ)`` pulled back from the position and orientation
   errors ⇒ ``(M_ψ, f_ψ)``;
3. ``q̈_G = −M⁻¹ f`` and ``q̈_F = −(M + M_ψ)⁻¹ (f + f_ψ)`` in one batched solve;
4. speed control (:mod:`tamedpuma.fabrics.speed`): ``q̈ = q̈_F − (α_ex + β) q̇``.

Steps 1-3 run as a fixed, small number of numpy calls on one design matrix of all leaf rows
(:mod:`~tamedpuma.fabrics.fused`); :meth:`Fabric.forcing` and the functions of
:mod:`~tamedpuma.fabrics.leaves` and :mod:`~tamedpuma.fabrics.energy` are the same maths leaf by
leaf (the tests check one against the other).

TamedPUMA's FPM and CPM reuse step 1 (:meth:`Fabric.avoidance`),
:meth:`AvoidanceFabric.acceleration` and :func:`tamedpuma.fabrics.energy.energize` /
:meth:`AvoidanceFabric.alpha`.
numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np

from tamedpuma.fabrics import compiled
from tamedpuma.fabrics.discrete import FarRows
from tamedpuma.fabrics.energy import attractor_blocks
from tamedpuma.fabrics.fused import LayoutBuffers, orientation_maps
from tamedpuma.fabrics.gains import FabricGains
from tamedpuma.fabrics.leaves import goal_errors
from tamedpuma.fabrics.spec import FabricError, Spec, solve_acceleration
from tamedpuma.fabrics.speed import speed_terms
from tamedpuma.robot.rotations import quat_to_matrix

try:  # the LAPACK gesv gufunc behind np.linalg.solve, without its Python wrapper
    from numpy.linalg._umath_linalg import solve1 as _solve
except ImportError:  # pragma: no cover - other numpy layouts
    _solve = None
_min = np.minimum.reduce


@dataclass(slots=True)
class AvoidanceFabric:
    """The unforced fabric in joint space, ``M q̈ + f = 0`` (a result: treat as read-only).

    M (n, n) SPD metric (= pulled energy metric, incl. base); forces (2, n): rows f (the geometry
    force) and f_energy (the pulled force of the fabric energy L_e); energy: ``H_{L_e}``;
    min_clearance [m]: smallest ``‖c_i − o_j‖ − r_i − r_j`` (inf without obstacles);
    ground_clearance [m] (inf when the ground leaf is off); n_clamped: barrier distances clamped
    to the margin (obstacle/ground pairs); n_limit_clamped: joint-limit distances clamped;
    barrier_rows (R, n), barrier_x (R,): every barrier's Jacobian row ∂x/∂q and distance x, not
    clamped (≤ 0 past a barrier), rate ẋ (with a moving obstacle's own motion: ẋ − a·q̇ is
    the row's drift), curvature J̇q̇ and metric m (``M = m_b I + Σ m_r a_r a_rᵀ``
    over these rows) (pairs, joint limits, ground; not the base rows), for the discrete-time
    barrier step and the directional forcing
    (:func:`tamedpuma.fabrics.discrete.barrier_step`). With many pairs, the pairs at or
    beyond the obstacle leaf's activation distance (metric 0) have no row here: far_rows
    (:class:`~tamedpuma.fabrics.discrete.FarRows`, else None) bounds them for the barrier step
    and builds their rows on demand. n_ground_rows: how many of the rows (the last ones) are
    ground rows (0 without the ground leaf); n_pair_rows: how many (the first ones) are obstacle
    pairs (the joint-limit rows, 2n, come between).
    """

    M: np.ndarray
    forces: np.ndarray
    energy: float
    min_clearance: float
    ground_clearance: float
    n_clamped: int
    n_limit_clamped: int
    barrier_rows: np.ndarray | None = None
    barrier_x: np.ndarray | None = None
    barrier_jdqd: np.ndarray | None = None
    barrier_metric: np.ndarray | None = None
    barrier_xd: np.ndarray | None = None
    far_rows: FarRows | None = None
    n_ground_rows: int = 0
    n_pair_rows: int = 0

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

    def alpha(self, qd, qdd, eps: float = 1e-6, Mqd=None) -> float:
        """Energization coefficient of ``q̈ = qdd`` w.r.t. the fabric energy L_e:
        ``α = q̇ᵀ(M q̈ + f_L)/(q̇ᵀ M q̇ + ε)`` [1/s]; then ``qdd − α q̇`` conserves ``H_{L_e}``.
        Mqd: ``M q̇`` where the caller has it already."""
        if Mqd is None:
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
        """Every field as a float, in declaration order (``asdict`` without its deep copy)."""
        return {k: float(getattr(self, k)) for k in _DIAGNOSTIC_FIELDS}


_DIAGNOSTIC_FIELDS = tuple(f.name for f in fields(FabricDiagnostics))


quaternion_to_rotation = quat_to_matrix  # re-exported for the fabrics API


class FabricBuffers:
    """The work buffers of one :class:`Fabric`'s calls: one
    :class:`~tamedpuma.fabrics.fused.LayoutBuffers` per layout (k spheres, m obstacles), built on
    first use, then reused. A call overwrites every entry it reads before reading it, so nothing
    in them carries from one call to the next: they are scratch, not state. A controller keeps
    one in its episode state (so a step writes nothing else); a copy (``copy.deepcopy`` of an
    episode) starts with none, which gives the same numbers. One per thread."""

    def __init__(self, fabric: Fabric):
        self.fabric = fabric
        self.layouts: dict[tuple[int, int], LayoutBuffers] = {}

    def layout(self, k: int, m: int) -> LayoutBuffers:
        """The buffers of the layout (k spheres, m obstacles): built on first use (cheap; no
        geometry is built, only arrays), then reused."""
        ws = self.layouts.get((k, m))
        if ws is None:
            if len(self.layouts) > 64:
                self.layouts.clear()
            f = self.fabric
            ws = self.layouts[(k, m)] = LayoutBuffers(f.gains, k, m, f.n, len(f.axes), f.q_min,
                                                      f.q_max)
        return ws

    def __deepcopy__(self, memo) -> FabricBuffers:
        return FabricBuffers(self.fabric)  # the fabric is configuration, never written: shared


class Fabric:
    """Geometric fabric of one robot (see the module docstring).

    gains: :class:`FabricGains`; q_min, q_max: (n,) joint limits [rad]. Fixed after
    construction: the work buffers of a call are the ``buffers`` given to it (a
    :class:`FabricBuffers` of :meth:`buffers`; none: fresh ones for that call). Returned arrays
    are always fresh.
    """

    def __init__(self, gains: FabricGains, q_min, q_max):
        self.gains = gains
        self.q_min = np.array(q_min, dtype=float)
        self.q_max = np.array(q_max, dtype=float)
        self.n = self.q_min.shape[0]
        axes = list(gains.orientation_axes) if gains.orientation_weight > 0 else []
        self.axes = axes
        self._offsets = gains.orientation_offset * np.eye(3)[axes]
        self._tx, self._tb = orientation_maps(axes, gains.orientation_offset)
        self._weight_list = [gains.goal_weight] + [gains.orientation_weight] * len(axes)
        self.compiled = compiled.wanted(gains.kernel)  # the kernels of fabrics.compiled

    def buffers(self) -> FabricBuffers:
        """Fresh work buffers for this fabric's calls (what an episode state keeps)."""
        return FabricBuffers(self)

    def _barriers(self, state, q, qd, obstacle_centers, obstacle_radii, obstacle_velocities,
                  buffers: FabricBuffers | None):
        """Fill a layout's barrier rows; returns (its buffers, H_{L_e}, n_clamped, n_limit)."""
        own = buffers if buffers is not None else self.buffers()
        if self.compiled:  # the compiled kernels' argument types: writable C arrays, always
            qd, obstacle_centers = _own(qd), _own(obstacle_centers)
            obstacle_radii, obstacle_velocities = _own(obstacle_radii), _own(obstacle_velocities)
        ws = own.layout(state.sphere_centers.shape[0], obstacle_centers.shape[0])
        n_clamped, n_limit = ws.barrier_rows(state, q, qd, obstacle_centers, obstacle_radii,
                                             obstacle_velocities, self.gains)
        return ws, ws.barrier_kernel(), n_clamped, n_limit

    def prepare(self, state, q, obstacle_centers, obstacle_radii, obstacle_velocities,
                goal_position=None, goal_rotation=None,
                buffers: FabricBuffers | None = None) -> None:
        """One :meth:`avoidance` (and with a goal one :meth:`evaluate`) at rest at (q, state)
        among the obstacles, the results dropped: the compiled kernels (``kernel`` numba, or
        auto with numba installed) compile, or load from numba's cache, for this layout's
        argument types and the ``buffers`` are allocated for it, before an episode's first step
        rather than inside it. A state the fabric refuses (FabricError) is left for the step."""
        if not self.compiled:
            return
        rest = np.zeros(self.n)
        try:
            self.avoidance(state, q, rest, obstacle_centers, obstacle_radii,
                           obstacle_velocities, buffers)
            if goal_position is not None:
                self.evaluate(state, q, rest, obstacle_centers, obstacle_radii,
                              obstacle_velocities, goal_position, goal_rotation, buffers)
        except FabricError:
            pass

    def prepare_at_start(self, kinematics, scenario, buffers: FabricBuffers | None,
                         with_goal: bool = False) -> None:
        """:meth:`prepare` at the scenario's start: q0 at rest, the obstacles at t = 0 and,
        with ``with_goal``, the goal (kinematics: the controller's, whose ``evaluate`` gives
        the state)."""
        if not self.compiled:
            return
        q0 = np.asarray(scenario.q0, dtype=float)
        state = kinematics.evaluate(q0, np.zeros_like(q0))
        obstacles, goal = scenario.obstacles, scenario.goal
        self.prepare(state, q0, obstacles.centers, obstacles.radii, obstacles.velocities,
                     goal.position if with_goal else None,
                     quat_to_matrix(goal.quaternion) if with_goal else None, buffers)

    def avoidance(self, state, q, qd, obstacle_centers, obstacle_radii,
                  obstacle_velocities, buffers: FabricBuffers | None = None) -> AvoidanceFabric:
        """The unforced fabric at (q, q̇) among the obstacles (see :class:`AvoidanceFabric`).

        state: a KinematicState at (q, q̇) (body spheres used); q, qd (n,) [rad], [rad/s];
        obstacle_centers (m, 3) [m], obstacle_radii (m,) [m], obstacle_velocities (m, 3) [m/s];
        buffers: the work buffers to fill (:meth:`buffers`; None: fresh ones). Every leaf is a
        row block of :mod:`~tamedpuma.fabrics.fused`'s design matrix.
        """
        ws, energy, n_clamped, n_limit = self._barriers(
            state, q, qd, obstacle_centers, obstacle_radii, obstacle_velocities, buffers)
        mf = ws.avoidance_system()
        n = self.n
        clearance = float(_min(ws.clear_flat)) if ws.P else np.inf
        ground = ws.ground_clearance if ws.ground else np.inf
        v = ws.views  # the rows in use (with many pairs: the pairs within x_a, then the rest)
        x = v.x if ws.x_raw is None else ws.x_raw
        head, tail = v.head, v.tail  # pairs and limits; ground rows (maybe none)
        m, xd, jd = v.W0, v.xd, v.jd
        n_ground = tail.stop - tail.start if ws.ground else 0
        if ws.ground:
            rows = np.concatenate((v.Z[head, :n], v.Z[tail, :n]))
            x, jd = np.concatenate((x[head], x[tail])), np.concatenate((jd[head], jd[tail]))
            m, xd = np.concatenate((m[head], m[tail])), np.concatenate((xd[head], xd[tail]))
        else:  # contiguous copies (a fancy index over 5000 rows costs 70 µs)
            rows, x, jd = v.Z[head, :n].copy(), x[head].copy(), jd[head].copy()
            m, xd = m[head].copy(), xd[head].copy()
        return AvoidanceFabric(M=mf[:, :n].copy(), forces=mf[:, n:].T.copy(), energy=energy,
                               min_clearance=clearance, ground_clearance=ground,
                               n_clamped=n_clamped, n_limit_clamped=n_limit,
                               barrier_rows=rows, barrier_x=x, barrier_jdqd=jd,
                               barrier_metric=m, barrier_xd=xd,
                               far_rows=ws.far if v.lo else None, n_ground_rows=n_ground,
                               n_pair_rows=v.n_pairs)

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
                 goal_position, goal_rotation, buffers: FabricBuffers | None = None
                 ) -> tuple[np.ndarray, FabricDiagnostics]:
        """The vanilla Fabrics acceleration q̈ [rad/s²] at (q, q̇) and its diagnostics.

        Arguments as :meth:`avoidance` and :meth:`forcing`. Raises :class:`FabricError` on
        non-finite input or output (never a silent zero acceleration).
        """
        g = self.gains
        if self.compiled:  # as in _barriers
            qd, goal_position, goal_rotation = _own(qd), _own(goal_position), _own(goal_rotation)
        ws, energy, n_clamped, n_limit = self._barriers(
            state, q, qd, obstacle_centers, obstacle_radii, obstacle_velocities, buffers)
        psi, r = ws.goal_rows(state, qd, goal_position, goal_rotation, g, self._tx, self._tb,
                              self._weight_list)
        n = self.n
        if ws.compiled:  # the same three steps as below, compiled (fabrics.compiled)
            v = ws.views
            ws.compiled.systems_solve(v.Z, v.W0, ws.Rb - v.lo, qd, ws.Ms, ws.dot_values)
            dots = ws.dot_values
        else:
            ws.systems()  # Ms[0] = [M | f | f_L | …], Ms[1] = [M + M_ψ | f + f_ψ | …]
            # q̈_G = −M⁻¹f and q̈_F = −(M + M_ψ)⁻¹(f + f_ψ) in one batched solve. M is SPD
            # (base metric m_b > 0 plus PSD leaves), so never singular; non-finite input gives
            # NaN here, which reaches every dot product below and is reported once.
            if _solve is not None:
                _solve(ws.Msys, ws.rhs, out=ws.sol)  # sol = −[q̈_G, q̈_F]
            else:  # pragma: no cover - other numpy layouts
                ws.sol[:] = -solve_acceleration(ws.Msys, ws.rhs)
            ws.qd_col[:] = qd
            # q̇ᵀ[M | f | f_L | −q̈_G | −q̈_F | q̇]: q̇ᵀM, q̇ᵀf, q̇ᵀf_L, −q̇ᵀq̈_G, −q̇ᵀq̈_F, ‖q̇‖²
            dots = qd @ ws.dots
        qMq = float(dots[:n] @ qd)
        qf, qfl, neg_qg, neg_qF, speed_sq = dots[n:].tolist()
        # α_G = q̇ᵀ(M q̈_G + f_L)/(q̇ᵀMq̇ + ε) = q̇ᵀ(f_L − f)/(q̇ᵀMq̇ + ε), since M q̈_G = −f.
        alpha_g = (qfl - qf) / (qMq + g.energization_eps)
        sp = speed_terms(speed_sq, -neg_qg, -neg_qF, alpha_g, r[0], g)
        c = sp.alpha_ex + sp.beta
        # q̇ᵀq̈_F finite ⇒ every component of q̈_F finite (NaN·0 = ∞·0 = NaN)
        if not (math.isfinite(neg_qF) and math.isfinite(c)):
            raise FabricError("fabric acceleration is not finite (non-finite input?)")
        qdd = np.subtract(qd * -c, ws.sol_forced)  # q̈ = q̈_F − (α_ex + β) q̇
        clearance = float(_min(ws.clear_flat)) if ws.P else np.inf
        ground = ws.ground_clearance if ws.ground else np.inf
        diag = FabricDiagnostics(
            energy_fabric=energy, energy_execution=speed_sq, potential=psi,
            alpha_geometry=alpha_g, alpha_0=sp.alpha_0, alpha_psi=sp.alpha_psi,
            alpha_ex=sp.alpha_ex, eta=sp.eta, beta=sp.beta, min_clearance=clearance,
            ground_clearance=ground, n_clamped=n_clamped, n_limit_clamped=n_limit,
            goal_distance=r[0], orientation_error=sum(r[1:]))
        return qdd, diag


def _own(a) -> np.ndarray:
    """A writable C-contiguous float copy of a (the one argument type the compiled kernels are
    compiled for, whatever the caller's arrays: read-only observations, views)."""
    return np.array(a, dtype=float)
