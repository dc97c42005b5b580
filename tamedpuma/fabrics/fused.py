"""The fabric's hot path: every leaf as rows of one design matrix, in preallocated buffers.

Same maths as :mod:`~tamedpuma.fabrics.leaves`, :mod:`~tamedpuma.fabrics.energy` and
:func:`~tamedpuma.fabrics.spec.pull_rows` (which stay the readable reference, and are what the tests
check this against), rearranged so that one evaluation is a fixed, small number of numpy calls
whatever the obstacle count (at 2 obstacles the time is per-call overhead, not arithmetic).

Every leaf is a set of one-dimensional task variables p with a Jacobian row ``a_p`` (n,), a scalar
metric ``m_p`` and a pulled force; their pullback is ``Σ_p m_p a_p a_pᵀ`` and ``Σ_p a_p b_p``
(method.md §2). Rows of the design matrix ``Z`` (R, n + 2) are ``[a_p | h_p + (J̇q̇)_p | κ_p +
(J̇q̇)_p]``, so that with ``C = diag(m) Z``:

    Zᵀ C = [Σ m a aᵀ | Σ a m (h + J̇q̇) | Σ a m (κ + J̇q̇)] = [M | f | f_L]

since a barrier leaf's geometry force is ``f_p = m_p h_p`` and its energy force
``f_{L,p} = −p_L H_p / x_p = m_p κ_p`` with ``κ_p = −p_L ẋ_p² / (2 x_p)`` (``H = ½ m ẋ²``).
One matrix product therefore gives the metric and both pulled forces. Row blocks, in order:

- ``P = k·m`` sphere × obstacle pairs (rows ``u_ijᵀ J_i``, see
  :func:`~tamedpuma.fabrics.leaves.sphere_obstacle_pairs`);
- ``n`` lower and ``n`` upper joint limits (rows ``±e_j``, constant, ``J̇q̇ = 0``);
- ``n`` base rows ``e_j`` with the constant metric ``m_b`` (``x = 1``, ``ẋ = q̇_j``): the base energy
  ``½ m_b ‖q̇‖²`` as a barrier leaf with exponents 0 and no geometry, so that the kernel also returns
  its energy;
- ``k`` ground rows ``(J_i)_z`` (only with the ground leaf);
- ``3K`` goal-attractor rows (K = 1 + number of orientation axes), metric ``g_k`` per block and
  force column ``J̇q̇ + ∇ψ`` (``f_ψ = Σ g Jᵀ(J̇q̇ + ∇ψ)``). The product over the barrier and base
  rows gives the unforced ``[M | f | f_L]``, the product over all rows the forced
  ``[M + M_ψ | f + f_ψ]`` (or, with many pairs, the goal rows' product added to the former).

With many pairs and a finite activation distance x_a (``fabric.obstacle_activation``), only the
pairs with ``x < x_a`` get rows (:func:`pair_rows_at`): a pair at ``x ≥ x_a`` has metric 0 and adds
exactly 0 to M, f and f_L, so its Jacobian row, rate and curvature are never built. The active
pairs are written to the *end* of the pair block, rows ``[lo, P)``, so that the rows in use,
``[lo, R)``, stay one contiguous block of every buffer (:class:`RowViews`). Sums over fewer rows
change the products' summation order only (rounding, ~1e-16 relative).

A :class:`LayoutBuffers` holds the buffers and their views for one layout (k spheres, m obstacles);
:class:`~tamedpuma.fabrics.fabric.Fabric` caches one per layout. Not thread-safe (one per Fabric).
numpy only.
"""

from __future__ import annotations

import numpy as np

from tamedpuma.fabrics import compiled
from tamedpuma.fabrics.discrete import FarRows
from tamedpuma.fabrics.energy import attractor_blocks
from tamedpuma.fabrics.gains import FabricGains
from tamedpuma.robot.rotations import SKEW_GENERATORS as _SKEW  # skew(v).ravel() = v @ _SKEW

# without the ndarray-method wrappers
_min, _max, _sum = np.minimum.reduce, np.maximum.reduce, np.add.reduce


def orientation_maps(axes, offset: float) -> tuple[np.ndarray, np.ndarray]:
    """Constant linear maps of ``R.ravel()`` (row-major rotation entries) for the orientation
    vectors ``x_k = R a_k``, ``a_k = offset · e_{axes[k]}``: returns ``T_x`` (9, 3A) with
    ``R.ravel() @ T_x = [x_1; …; x_A]`` and ``T_B`` (3A, 3, 9) with ``T_B @ R.ravel()`` the
    stack of ``−[x_k]×`` (3A, 3), the Jacobian map ``J_k = −[x_k]× J_ω``."""
    A = len(axes)
    tx = np.zeros((9, 3 * A))
    for k, ax in enumerate(axes):
        for c in range(3):
            tx[3 * c + ax, 3 * k + c] = offset
    # −[x]× entries are linear in x: −skew(x).ravel() = −x @ _SKEW
    tb = np.zeros((9, 9 * A))
    for k in range(A):
        tb[:, 9 * k:9 * k + 9] = -tx[:, 3 * k:3 * k + 3] @ _SKEW
    return tx, tb.T.reshape(3 * A, 3, 9)


def kernel_constants(g: FabricGains, n_pairs: int, n: int,
                     n_ground: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per-row constants of the barrier kernel, three rows each (energy, geometry, energy force):
    ``negexp`` (3, Rb) the exponents ``[−p_L, −p_h, −1]``, ``gain`` (3, Rb) the factors
    ``[2 k_L, −k_h, −p_L/2]`` and ``threshold`` (3, Rb) of the switch ``s(ẋ) = [ẋ < threshold]``
    (0 when directional, +inf when always on), so that ``gain s x^{negexp}`` is
    ``[2 k_L s_L x^{−p_L}, −k_h s_h x^{−p_h}, −(p_L/2) x^{−1}]`` (times ẋ²: 2H, h, κ).
    Row blocks as the design matrix: pairs, 2n limits, n base rows (``m = m_b``, no geometry,
    no energy force), ground rows."""
    parts = [(g.obstacle, n_pairs), (g.joint_limit, 2 * n), (None, n)]
    if n_ground:
        parts.append((g.ground, n_ground))
    cols = []
    for bg, count in parts:
        if bg is None:  # base rows: m = m_b, H = ½ m_b q̇², no geometry, no energy force
            col = ((0.0, g.base_metric, np.inf), (0.0, 0.0, np.inf), (0.0, 0.0, np.inf))
        else:
            col = ((-bg.energy_exponent, 2.0 * bg.energy_gain,
                    0.0 if bg.energy_directional else np.inf),
                   (-bg.geometry_exponent, -bg.geometry_gain,
                    0.0 if bg.geometry_directional else np.inf),
                   (-1.0, -0.5 * bg.energy_exponent, np.inf))
        cols.append(np.repeat(np.array(col)[:, :, None], count, axis=2))
    negexp, gain, threshold = np.concatenate(cols, axis=2).transpose(1, 0, 2)
    return negexp.copy(), gain.copy(), threshold.copy()


def integer_powers(negexp: np.ndarray, n_pairs: int) -> tuple[int, ...] | None:
    """The pair rows' exponents ``(p_L, p_h, 1)`` as integers when each is a small
    non-negative integer (0…8), so that ``x^{−p}`` can be taken as products of ``1/x``;
    None otherwise or without pairs."""
    pair_p = [-float(e) for e in negexp[:, 0]] if n_pairs else []
    if pair_p and all(p == int(p) and 0 <= p <= 8 for p in pair_p):
        return tuple(int(p) for p in pair_p)
    return None


def pair_rows_at(d, inv_d, inv_r, si, oj, J, jdqd, Jq, ov):
    """Rate, curvature and Jacobian row of the sphere × obstacle pairs ``(si[p], oj[p])`` from
    their ``d = c_i − o_j`` (3, P'), ``1/‖d‖`` and ``1/R`` (P',) (as
    :meth:`LayoutBuffers._pair_rows` for every pair): ``ẋ = dᵀv/(‖d‖R)``,
    ``J̇q̇ = (dᵀa + ‖v‖² − (dᵀv/‖d‖)²)/(‖d‖R)``, rows ``(d/(‖d‖R))ᵀ J_i``, with
    ``v = J_i q̇ − ȯ_j`` (Jq: the spheres' ``J_i q̇`` (k, 3)), ``a = J̇_i q̇``.
    Returns fresh (ẋ (P',), J̇q̇ (P',), rows (P', n))."""
    Y = np.empty((3,) + d.shape)
    Y[0] = d
    np.subtract(Jq.T[:, si], ov.T[:, oj], out=Y[1])
    Y[2] = jdqd.T[:, si]
    G = np.einsum("adp,bdp->abp", Y[:2], Y)  # d·d, d·v, d·a; v·d, v·v, v·a
    w = inv_d * inv_r  # 1/(‖d‖R)
    xd = G[0, 1] * w
    s = G[0, 2] + G[1, 1]
    t = G[0, 1] * inv_d
    t *= t
    s -= t
    U = d * w  # u = ν/R
    rows = np.einsum("cp,pcn->pn", U, J[si])
    return xd, s * w, rows


class RowViews:
    """Views of the rows in use, ``[lo, R)`` (``lo = 0`` unless inactive pairs are left out,
    see the module docstring), of every buffer the kernel and the products read and write:
    ``x``, ``xd``, ``jd`` and the kernel arrays over ``[lo, Rb)``; ``Z``, ``C``, ``m_col`` over
    ``[lo, R)``; ``n_pairs = P − lo``; ``head``, ``tail``: the pair-and-limit rows and the
    ground rows, relative to lo."""

    __slots__ = ("lo", "n_pairs", "x", "xd", "jd", "negexp", "gain", "threshold", "S", "Wb",
                 "xd2", "T", "T0", "T12", "Zb_hl", "Z", "C", "m_col", "ZbT", "Cb", "W0",
                 "head", "tail", "ZT", "C_sys")

    def __init__(self, ws, lo: int):
        P, L, Rb, n = ws.P, ws.L, ws.Rb, ws.n
        self.lo, self.n_pairs = lo, P - lo
        self.x, self.xd, self.jd = ws.x[lo:], ws.xd[lo:], ws.jd[lo:]
        self.negexp, self.gain = ws.negexp[:, lo:], ws.gain[:, lo:]
        self.threshold, self.S = ws.threshold[:, lo:], ws.S[:, lo:]
        self.Wb, self.xd2, self.T = ws.Wb[:, lo:], ws.xd2[lo:], ws.T[:, lo:]
        self.T0, self.T12 = self.T[0], self.T[1:]
        self.Zb_hl = ws.Zb_hl[:, lo:]
        self.Z, self.C, self.m_col = ws.Z[lo:], ws.C[lo:], ws.m_col[lo:]
        self.ZbT, self.Cb = ws.ZbT[:, lo:], ws.Cb[lo:]
        self.ZT, self.C_sys = ws.ZT[:, lo:], ws.C_sys[lo:]
        self.W0 = ws.W[0][lo:]
        self.head, self.tail = slice(0, P + 2 * n - lo), slice(L - lo, Rb - lo)


class LayoutBuffers:
    """Buffers and views of one layout: k body spheres, m obstacles, n joints, K goal blocks,
    optional ground rows (see the module docstring for the row layout).

    Row offsets: pairs ``[0, P)``, limits ``[P, P + 2n)``, base rows ``[P + 2n, L)``, ground
    rows ``[L, Rb)``, goal rows ``[Rb, R)``. Each ``_build_*`` method allocates one group of
    buffers and the views into it that the evaluation methods below write and read."""

    def __init__(self, gains: FabricGains, k: int, m: int, n: int, n_axes: int, q_min, q_max):
        ground = k if gains.ground_enabled else 0
        self.k, self.m, self.n, self.n_axes = k, m, n, n_axes
        self.P = k * m
        self.L = self.P + 3 * n  # end of pairs, limits and base rows
        self.Rb = self.L + ground  # barrier-like rows (kernel length)
        self.K = 1 + n_axes
        self.R = self.Rb + 3 * self.K
        self.split = self.Rb > 256  # many rows: products split by row block (see systems())
        self.ground = bool(ground)
        # barrier rows without the base rows: pairs, limits, ground (two contiguous blocks)
        self.barrier_index = np.r_[0:self.P + 2 * n, self.L:self.Rb]
        self.barrier_blocks = (slice(0, self.P + 2 * n), slice(self.L, self.Rb))
        self.q_min, self.q_max = np.array(q_min, dtype=float), np.array(q_max, dtype=float)
        # fabric.kernel numba (auto where numba is installed): the pair rows, the kernel and the
        # goal rows by :mod:`compiled` (the numpy code below is the reference it is tested
        # against)
        self.compiled = compiled.kernels() if compiled.wanted(gains.kernel) else None
        self._build_design_matrix()
        self._build_kernel_inputs()
        self._build_kernel_constants(gains)
        self._build_pair_scratch()
        self._build_goal_scratch()
        self._build_outputs()
        self.views = self._views0 = RowViews(self, 0)
        self._view_cache: dict[int, RowViews] = {0: self._views0}
        self.far = None  # the left-out pairs of the last call (gathered layouts)

    def _views_at(self, lo: int) -> RowViews:
        """The :class:`RowViews` from row lo (cached; the active count changes slowly)."""
        v = self._view_cache.get(lo)
        if v is None:
            if len(self._view_cache) > 64:
                self._view_cache = {0: self._views0}
            v = self._view_cache[lo] = RowViews(self, lo)
        return v

    def _build_design_matrix(self) -> None:
        """``Z = [a | h + J̇q̇ | κ + J̇q̇]`` (R, n + 2) with its constant rows (limits ``±e_j``,
        base ``e_j``) written once, ``C = diag(m) Z`` and their row-block views."""
        P, L, Rb, n = self.P, self.L, self.Rb, self.n
        Z = self.Z = np.zeros((self.R, n + 2))
        eye = np.eye(n)
        Z[P:P + n, :n] = eye
        Z[P + n:P + 2 * n, :n] = -eye
        Z[P + 2 * n:L, :n] = eye
        self.Zp = Z[:P, :n].reshape(self.k, self.m, n)
        self.ZbT = Z[:Rb, :n].T
        self.Zg_all = Z[Rb:]
        self.Zg_ori_h = Z[Rb + 3:, n]
        self.Y_ori = Z[Rb + 3:, n + 1].reshape(self.n_axes, 3)  # ω × x_k (column otherwise unused)
        self.Zg_h = Z[Rb:, n]
        self.Zb_hl = Z[:Rb, n:].T  # (2, Rb) view: columns h + J̇q̇ and κ + J̇q̇
        if self.ground:
            self.Zground = Z[L:Rb, :n]
        self.C = np.empty((self.R, n + 2))
        self.ZT, self.C_sys = Z[:, :n].T, self.C[:, :n + 1]
        self.ZgT, self.Cg = Z[Rb:, :n].T, self.C[Rb:, :n + 1]
        self.Cb = self.C[:Rb]

    def _build_kernel_inputs(self) -> None:
        """``X = [x; ẋ]`` (2, Rb) and ``J̇q̇`` (Rb,) of every barrier-like row, with the views
        each row block writes (base rows: x = 1 once, since x^0 = 1 and κ = 0 there)."""
        P, L, Rb, n = self.P, self.L, self.Rb, self.n
        X = self.X = np.empty((2, Rb))
        X[0, P + 2 * n:L] = 1.0
        self.x, self.xd = X[0], X[1]
        self.x_lo, self.x_hi = X[0, P:P + n], X[0, P + n:P + 2 * n]
        self.xd_lo, self.xd_hi = X[1, P:P + n], X[1, P + n:P + 2 * n]
        self.xd_base = X[1, P + 2 * n:L]
        self.xp, self.xdp = X[0, :P].reshape(self.k, self.m), X[1, :P].reshape(self.k, self.m)
        self.jd = np.zeros(Rb)
        self.jdp = self.jd[:P].reshape(self.k, self.m)
        if self.ground:
            self.x_gr, self.xd_gr = X[0, L:Rb], X[1, L:Rb]
            self.jd_gr = self.jd[L:Rb]

    def _build_kernel_constants(self, g: FabricGains) -> None:
        """The kernel's per-row constants (:func:`kernel_constants`), the integer exponents of
        the pair rows when many pairs make ``np.power`` the kernel's main cost
        (:func:`integer_powers`), and the kernel's scratch: ``W`` (3, R) with ``W[:, :Rb]`` the
        kernel rows (``W[0] = m``) and, on the goal rows, ``W[0] = g_k``, ``W[1] = c_k``
        (``∇ψ = c e``); ``T`` (3, Rb) = ``[2H, h, κ]``."""
        Rb = self.Rb
        self.negexp, self.gain, self.threshold = kernel_constants(
            g, self.P, self.n, Rb - self.L)
        self.pair_powers = integer_powers(self.negexp, self.P) if self.split else None
        xa = g.obstacle_activation
        self.activation = float(xa) if np.isfinite(xa) and self.P else None
        # many pairs and a finite x_a: rows only for the pairs with x < x_a (pair_rows_at)
        self.gather = self.activation is not None and self.split
        self.taper_t = np.empty(self.P)
        self.taper_on = np.empty(self.P, dtype=bool)
        self.inv_x = np.empty(self.P)
        self.far_mask = np.empty((self.k, self.m), dtype=bool)
        self.S = np.empty((3, Rb), dtype=bool)
        self.xd2 = np.empty(Rb)
        W = self.W = np.empty((3, self.R))
        self.Wb = W[:, :Rb]
        self.m_col = W[0][:, None]
        self.Wg = W[:2, Rb:].reshape(2, self.K, 3)
        self.ratio_rows = W[1, Rb:]
        self.T = np.empty((3, Rb))
        self.T0, self.T12 = self.T[0], self.T[1:]

    def _build_pair_scratch(self) -> None:
        """Scratch of the sphere × obstacle pairs, component first (contiguous over the pairs):
        ``Y = [d, v, a]`` (3, 3, k, m), the Gram entries ``G`` (2, 3, k, m), distances, radii and
        the rows ``u = ν/R`` (3, k, m)."""
        k, m = self.k, self.m
        self.Y = np.empty((3, 3, k, m))
        self.d, self.v, self.a = self.Y[0], self.Y[1], self.Y[2]
        self.Y2 = self.Y[:2]
        self.G = np.empty((2, 3, k, m))
        self.dd, self.dv, self.da = self.G[0, 0], self.G[0, 1], self.G[0, 2]
        self.vv = self.G[1, 1]
        self.inv_d = np.empty((k, m))
        self.dist = np.empty((k, m))
        self.big_r = np.empty((k, m))
        self.inv_r = np.empty((k, m))
        self.w = np.empty((k, m))
        self.clear = self.G[0, 0]  # written over d·d once ‖d‖ is known
        self.clear_flat = self.clear.reshape(-1)
        self.s = np.empty((k, m))
        self.t = np.empty((k, m))
        self.U = np.empty((3, k, m))
        self.Ut = self.U.transpose(1, 2, 0)

    def _build_goal_scratch(self) -> None:
        """Scratch of the goal rows: errors ``E`` (3K,), ``R − R_g``, the end effector's
        ``[J | J̇q̇ | ω]`` (6, n + 2) (ω in the angular rows) and the block map
        ``B = diag(I₃, B_1 … B_A)`` (3K, 6), so that the goal rows ``[a | J̇q̇ | ·] = B @ ext``
        (``ω × x_k = B_k ω``), the curvature ``ω × (ω × x_k)`` and ``[g_k, c_k]``."""
        K, n = self.K, self.n
        self.E = np.empty(3 * K)
        self.E_pos, self.E_ori = self.E[:3], self.E[3:]
        self.EK = self.E.reshape(K, 3)
        self.dR = np.empty((3, 3))
        self.dR9 = self.dR.reshape(9)
        self.ext = np.zeros((6, n + 2))
        self.ext_J, self.ext_a = self.ext[:, :n], self.ext[:, n]
        self.ext_Jw, self.omega = self.ext[3:, :n], self.ext[3:, n + 1]
        self.Bfull = np.zeros((3 * K, 6))
        self.Bfull[:3, :3] = np.eye(3)
        self.B = self.Bfull[3:, 3:]
        self.om_skew = np.empty(9)
        self.om_skewT = self.om_skew.reshape(3, 3).T
        self.curv = np.empty((self.n_axes, 3))
        self.curv_flat = self.curv.reshape(-1)
        self.gscratch = np.empty(3 * K)
        self.blocks = np.kron(np.eye(K), np.ones((3, 1)))  # (3K, K): Σ over each block's rows
        self.sq = np.empty(K)  # ‖e_k‖²
        self.gk = np.empty(2 * K)  # [g_1 … g_K, c_1 … c_K]
        self.gk_rows = self.gk.reshape(2, K, 1)

    def _build_outputs(self) -> None:
        """The stacked systems ``Ms`` (2, n, n + 5): ``Ms[0] = [M | f | f_L | M⁻¹f |
        (M + M_ψ)⁻¹(f + f_ψ) | q̇]`` so that one product ``q̇ᵀMs[0]`` gives every dot product
        speed control needs; ``Ms[1, :, :n+1] = [M + M_ψ | f + f_ψ]``."""
        n = self.n
        self.Ms = np.empty((2, n, n + 5))
        self.Mf0 = self.Ms[0, :, :n + 2]
        self.Mf1 = self.Ms[1, :, :n + 1]
        self.Mf0_sys = self.Ms[0, :, :n + 1]
        self.Msys, self.rhs = self.Ms[:, :, :n], self.Ms[:, :, n]
        self.sol = self.Ms[0, :, n + 2:n + 4].T  # (2, n): M⁻¹f, (M + M_ψ)⁻¹(f + f_ψ)
        self.sol_forced = self.Ms[0, :, n + 3]
        self.qd_col = self.Ms[0, :, n + 4]
        self.dots = self.Ms[0]
        self.dot_values = np.empty(n + 5)  # q̇ᵀ Ms[0] (compiled path)

    def barrier_rows(self, state, q, qd, obs_centers, obs_radii, obs_velocities,
                     g: FabricGains) -> tuple[int, int]:
        """Fill x, ẋ, J̇q̇ and the Jacobian rows of the pairs, limits, base and ground rows
        (gathered layouts: only the pairs with x < x_a, see :meth:`_gathered_pair_rows`) and
        select their :class:`RowViews`.

        Returns ``(n_clamped, n_limit_clamped)`` (distances below the margin, clamped up to it).
        """
        lo = 0
        if self.gather:
            lo = self._gathered_pair_rows(state, qd, obs_centers, obs_radii, obs_velocities)
        elif self.compiled:
            self.compiled.pair_rows(state.sphere_centers, state.sphere_jacobians,
                                    state.sphere_jdqd, state.sphere_radii, qd, obs_centers,
                                    obs_radii, obs_velocities, self.xp, self.xdp, self.jdp,
                                    self.Zp, self.clear)
        else:
            self._pair_rows(state, qd, obs_centers, obs_radii, obs_velocities)
        v = self.views = self._views0 if lo == 0 else self._views_at(lo)
        self._other_rows(state, q, qd, g)
        x, margin = v.x, g.barrier_margin
        n_limit = n_clamped = 0
        self.x_raw = None  # the distances before clamping (only kept when some are clamped)
        if _min(x) < margin:  # rare: penetration or a start on/past a limit
            self.x_raw = x.copy()
            P, L, n = v.n_pairs, self.L - lo, self.n
            n_clamped = int(np.count_nonzero(x[:P] < margin) + np.count_nonzero(x[L:] < margin))
            n_limit = int(np.count_nonzero(x[P:L - n] < margin))  # not the base rows
            np.maximum(x, margin, out=x)
        return n_clamped, n_limit

    def _gathered_pair_rows(self, state, qd, obs_centers, obs_radii, obs_velocities) -> int:
        """Many pairs: every pair's distance x and clearance (one pass of a few calls), then
        rate, curvature and Jacobian row of the active pairs only (``x < x_a``, or not finite:
        NaN must reach the result) by :func:`pair_rows_at`, written to rows ``[lo, P)``.
        Returns lo. The left-out pairs (``x ≥ x_a``: metric 0, no contribution to M, f, f_L)
        are described by :attr:`far` (a :class:`~tamedpuma.fabrics.discrete.FarRows`) for the
        control-rate barrier step. A non-finite obstacle velocity keeps every pair."""
        speed2 = float(_max(np.einsum("jd,jd->j", obs_velocities, obs_velocities)))
        if self.compiled:
            lo = self.compiled.near_pair_rows(
                state.sphere_centers, state.sphere_jacobians, state.sphere_jdqd,
                state.sphere_radii, qd, obs_centers, obs_radii, obs_velocities, self.activation,
                not np.isfinite(speed2), self.x, self.xd, self.jd, self.Z, self.clear,
                self.far_mask)
            far = self.far_mask
        else:
            lo, far = self._near_pair_rows(state, qd, obs_centers, obs_radii, obs_velocities,
                                           speed2)
        self.far = None if lo == 0 else FarRows(
            clearance=self.activation * (state.sphere_radii + float(_min(obs_radii))),
            jacobians=state.sphere_jacobians, jdqd_norm=np.sqrt(np.einsum(
                "kd,kd->k", state.sphere_jdqd, state.sphere_jdqd)),
            obstacle_speed=speed2 ** 0.5,
            rows=_FarPairRows(state, qd, obs_centers, obs_radii, obs_velocities, far.copy()),
            activation=self.activation)
        return lo

    def _near_pair_rows(self, state, qd, obs_centers, obs_radii, obs_velocities, speed2):
        """The numpy part of :meth:`_gathered_pair_rows`: returns (lo, the far mask)."""
        P, m = self.P, self.m
        d = self.d
        np.subtract(state.sphere_centers.T[:, :, None], obs_centers.T[:, None, :], out=d)
        dd = self.dd
        np.einsum("dkm,dkm->km", d, d, out=dd)
        np.maximum(dd, 1e-24, out=dd)
        np.power(dd, -0.5, out=self.inv_d)  # 1/‖d‖ (as the full path: the same x, bit for bit)
        np.multiply(dd, self.inv_d, out=self.dist)  # ‖d‖
        np.add(state.sphere_radii[:, None], obs_radii, out=self.big_r)  # R = r_i + r_j
        np.subtract(self.dist, self.big_r, out=self.clear)  # ‖d‖ − R (over d·d)
        np.multiply(self.big_r, self.activation, out=self.s)  # x_a R
        far = np.greater_equal(self.clear, self.s, out=self.far_mask)  # x ≥ x_a (NaN: kept)
        if not np.isfinite(speed2):
            far[...] = False
        idx = np.flatnonzero(~far)
        lo = P - idx.size
        if idx.size:
            si, oj = np.divmod(idx, m)
            inv_d = self.inv_d.reshape(P)[idx]
            big_r = self.big_r.reshape(P)[idx]
            inv_r = np.divide(1.0, big_r)
            np.multiply(self.clear.reshape(P)[idx], inv_r, out=self.x[lo:P])  # x = ‖d‖/R − 1
            xd, jd, rows = pair_rows_at(self.d.reshape(3, P)[:, idx], inv_d, inv_r, si, oj,
                                        state.sphere_jacobians, state.sphere_jdqd,
                                        state.sphere_jacobians @ qd, obs_velocities)
            self.xd[lo:P] = xd
            self.jd[lo:P] = jd
            self.Z[lo:P, :self.n] = rows
        return lo, far

    def _pair_rows(self, state, qd, obs_centers, obs_radii, obs_velocities) -> None:
        """The sphere × obstacle pair rows: x, ẋ, J̇q̇, the clearances and the Jacobian rows
        (the numpy reference of ``tamedpuma.fabrics.compiled._pair_rows``)."""
        J = state.sphere_jacobians
        # pairs (leaves.sphere_obstacle_pairs): d = c_i − o_j, v = J_i q̇ − ȯ_j, a = J̇_i q̇
        np.subtract(state.sphere_centers.T[:, :, None], obs_centers.T[:, None, :], out=self.d)
        np.subtract((J @ qd).T[:, :, None], obs_velocities.T[:, None, :], out=self.v)
        self.a[...] = state.sphere_jdqd.T[:, :, None]
        np.einsum("adkm,bdkm->abkm", self.Y2, self.Y, out=self.G)  # d·d, d·v, d·a; v·v, …
        np.maximum(self.dd, 1e-24, out=self.dd)
        np.power(self.dd, -0.5, out=self.inv_d)  # 1/‖d‖
        np.multiply(self.dd, self.inv_d, out=self.dist)  # ‖d‖
        np.add(state.sphere_radii[:, None], obs_radii, out=self.big_r)  # R = r_i + r_j
        np.divide(1.0, self.big_r, out=self.inv_r)
        np.subtract(self.dist, self.big_r, out=self.clear)  # ‖d‖ − R (over d·d, now unused)
        np.multiply(self.inv_d, self.inv_r, out=self.w)  # 1/(‖d‖R)
        np.multiply(self.clear, self.inv_r, out=self.xp)  # x = ‖d‖/R − 1
        np.multiply(self.dv, self.w, out=self.xdp)  # ẋ = νᵀv/R
        # J̇q̇ = (νᵀa + (‖v‖² − (νᵀv)²)/‖d‖)/R = (dᵀa + ‖v‖² − (νᵀv)²)/(‖d‖R)
        np.add(self.da, self.vv, out=self.s)
        np.multiply(self.dv, self.inv_d, out=self.t)
        self.t *= self.t
        self.s -= self.t
        np.multiply(self.s, self.w, out=self.jdp)
        np.multiply(self.d, self.w, out=self.U)  # u = ν/R: pair row uᵀJ_i
        np.matmul(self.Ut, J, out=self.Zp)

    def _other_rows(self, state, q, qd, g: FabricGains) -> None:
        """Joint-limit, base and ground rows."""
        J = state.sphere_jacobians
        # joint limits [q − q_min, q_max − q] with ẋ [q̇, −q̇], base rows ẋ = q̇ (flat 1-d calls
        # are cheaper than one broadcast call)
        np.subtract(q, self.q_min, out=self.x_lo)
        np.subtract(self.q_max, q, out=self.x_hi)
        self.xd_lo[:] = qd
        np.negative(qd, out=self.xd_hi)
        self.xd_base[:] = qd
        if self.ground:
            Jz = J[:, 2, :]
            np.subtract(state.sphere_centers[:, 2], state.sphere_radii, out=self.x_gr)
            self.x_gr -= g.ground_height
            np.matmul(Jz, qd, out=self.xd_gr)
            self.jd_gr[:] = state.sphere_jdqd[:, 2]
            self.Zground[:] = Jz
            self.ground_clearance = float(self.x_gr.min())

    def barrier_kernel(self) -> float:
        """Metric, geometry and energy columns of every barrier-like row in use
        (energy.barrier_leaf): ``m = 2 k_L s_L x^{−p_L}``, ``h = −k_h s_h ẋ² x^{−p_h}``,
        ``κ = −p_L ẋ²/(2x)``, as one power, two products with per-row constants and one
        product with ẋ² for all three. Returns the energy ``Σ H = ½ Σ m ẋ²``."""
        v = self.views
        if self.compiled:
            return self.compiled.kernel(v.x, v.xd, v.negexp, v.gain, v.threshold, v.jd, v.Wb,
                                        v.T, v.Zb_hl, v.n_pairs,
                                        np.inf if self.activation is None else self.activation)
        x, xd, Wb = v.x, v.xd, v.Wb
        np.less(xd, v.threshold, out=v.S)  # s(ẋ)
        if self.pair_powers is None or v.n_pairs < 256:
            np.power(x, v.negexp, out=Wb)
        else:  # many pairs: x^{−p} of the pair rows by products of 1/x (p small integers)
            P = v.n_pairs
            np.power(x[P:], v.negexp[:, P:], out=Wb[:, P:])
            inv = np.divide(1.0, x[:P], out=self.inv_x[:P])
            for row, p in zip(Wb[:, :P], self.pair_powers):
                row[...] = inv if p else 1.0
                for _ in range(p - 1):
                    row *= inv
        Wb *= v.gain
        Wb *= v.S  # Wb = [m, −k_h s_h x^{−p_h}, −p_L/(2x)]
        if self.activation is not None and v.n_pairs:
            self._taper_pairs(x[:v.n_pairs], Wb[0, :v.n_pairs], Wb[2, :v.n_pairs])
        xd2 = np.multiply(xd, xd, out=v.xd2)
        np.multiply(Wb, xd2, out=v.T)  # [m ẋ² = 2H, h, κ]
        np.add(v.T12, v.jd, out=v.Zb_hl)
        return 0.5 * float(_sum(v.T0))

    def _taper_pairs(self, x, m, kappa) -> None:
        """The obstacle leaf's activation taper on the pair rows (energy.barrier_energy):
        ``m ← w m`` and ``κ/ẋ² ← −p_L/(2x) + w'/(2w) = −p_L/(2x) − 2x/(x_a² t)`` with
        ``w = t²``, ``t = 1 − (x/x_a)²`` below x_a; beyond it m = 0 and that column is 0.
        x, m, kappa: the pair rows' x and the kernel's m and κ/ẋ² rows (views). When every
        pair is below x_a (always after the gathering of many pairs) the clamp and the mask are
        skipped: the same values, three calls fewer; when every pair is at or beyond x_a
        (common with a few obstacles) m and κ are set to 0 in two calls."""
        xa = self.activation
        if _min(x) >= xa:  # every pair inactive
            m[...] = 0.0
            kappa[...] = 0.0
            return
        t = np.multiply(x, x, out=self.taper_t[:x.shape[0]])
        t *= -1.0 / (xa * xa)
        t += 1.0
        some_off = _min(t) <= 0.0  # else every pair active: no clamp, no mask
        if some_off:
            np.maximum(t, 0.0, out=t)
            on = np.greater(t, 0.0, out=self.taper_on[:x.shape[0]])
        m *= t
        m *= t
        t *= -0.5 * xa * xa  # → −x_a² t / 2, so that x / that = −2x/(x_a² t)
        if some_off:
            np.divide(x, t, out=t, where=on)  # (0 where off: t is 0 there)
            kappa += t
            kappa *= on
        else:
            np.divide(x, t, out=t)
            kappa += t

    def goal_rows(self, state, qd, goal_position, goal_rotation, g: FabricGains, tx, tb,
                  weights):
        """Fill the goal-attractor rows (leaves.goal_errors, energy.attractor_blocks): Jacobian
        rows, ``J̇q̇ + ∇ψ`` and the metric g_k of every row. Returns ``(ψ, [‖e_k‖])``.

        Position block: ``e = p − p_g``, rows ``J_v``, ``J̇q̇_v``. Orientation block k:
        ``e_k = (R − R_g) a_k``, rows ``B_k J_ω`` with ``B_k = −[x_k]×``, ``x_k = R a_k``, and
        ``J̇q̇_k = B_k (J̇q̇)_ω + ω × (ω × x_k)``, ``ω = J_ω q̇`` (``ω × x_k = B_k ω``).
        """
        R = state.ee_rotation
        if self.compiled:
            self.compiled.goal_rows(R, state.ee_jacobian, state.ee_jdqd, qd, tb, tx,
                               state.ee_position, goal_position, goal_rotation, self.Zg_all,
                               self.E, self.sq)
            return self._goal_gains(g, weights, self.sq.tolist())
        self.ext_J[...] = state.ee_jacobian
        self.ext_a[...] = state.ee_jdqd
        np.matmul(self.ext_Jw, qd, out=self.omega)
        np.matmul(tb, R.reshape(9), out=self.B)
        np.matmul(self.Bfull, self.ext, out=self.Zg_all)
        np.matmul(self.omega, _SKEW, out=self.om_skew)
        np.matmul(self.Y_ori, self.om_skewT, out=self.curv)  # ω × (ω × x_k)
        self.Zg_ori_h += self.curv_flat
        # errors and the attractor's potential, gradient ratio c_k (∇ψ_k = c_k e_k), metric g_k
        np.subtract(state.ee_position, goal_position, out=self.E_pos)
        np.subtract(R, goal_rotation, out=self.dR)
        np.matmul(self.dR9, tx, out=self.E_ori)
        np.multiply(self.E, self.E, out=self.gscratch)
        return self._goal_gains(g, weights, (self.gscratch @ self.blocks).tolist())

    def _goal_gains(self, g: FabricGains, weights, squared: list[float]):
        """The attractor's potential, gradient ratio c_k (∇ψ_k = c_k e_k) and metric g_k of
        every block from its squared error; the goal rows' metric and ``J̇q̇ + ∇ψ`` column."""
        psi, r, ratio, gm = attractor_blocks(squared, g, weights)
        self.gk[:] = gm + ratio
        self.Wg[:] = self.gk_rows
        np.multiply(self.ratio_rows, self.E, out=self.gscratch)
        self.Zg_h += self.gscratch
        return psi, r

    def systems(self) -> None:
        """``Ms[0] = [M | f | f_L]`` (the fabric) and ``Ms[1, :, :n+1] = [M + M_ψ | f + f_ψ]``
        over the rows in use."""
        v = self.views
        np.multiply(v.m_col, v.Z, out=v.C)
        np.matmul(v.ZbT, v.Cb, out=self.Mf0)
        if self.split:  # many pairs: add the goal product rather than redo the barrier one
            np.matmul(self.ZgT, self.Cg, out=self.Mf1)
            self.Mf1 += self.Mf0_sys
        else:  # few rows: one product over all rows (barrier, base and goal) is one call less
            np.matmul(v.ZT, v.C_sys, out=self.Mf1)

    def avoidance_system(self) -> np.ndarray:
        """Fresh ``[M | f | f_L]`` (n, n + 2) of the fabric alone (barrier and base rows in
        use)."""
        v = self.views
        np.multiply(v.m_col[:v.Cb.shape[0]], v.Z[:v.Cb.shape[0]], out=v.Cb)
        return v.ZbT @ v.Cb


class _FarPairRows:
    """The left-out pairs' ``(rows, x, J̇q̇, drift = ẋ − a·q̇)``
    (:class:`~tamedpuma.fabrics.discrete.FarRows`
    ``.rows``), computed from the call's inputs only when asked (the barrier step's bound
    failed), with :func:`pair_rows_at`; far: the (k, m) mask of the left-out pairs."""

    __slots__ = ("state", "qd", "oc", "orad", "ov", "far")

    def __init__(self, state, qd, oc, orad, ov, far):
        self.state, self.qd, self.oc, self.orad, self.ov, self.far = state, qd, oc, orad, ov, far

    def __call__(self):
        st, m = self.state, self.oc.shape[0]
        si, oj = np.divmod(np.flatnonzero(self.far), m)
        d = st.sphere_centers.T[:, si] - self.oc.T[:, oj]
        dist = np.sqrt(np.maximum(np.einsum("dp,dp->p", d, d), 1e-24))
        inv_d = 1.0 / dist
        big_r = st.sphere_radii[si] + self.orad[oj]
        inv_r = 1.0 / big_r
        x = (dist - big_r) * inv_r
        xd, jd, rows = pair_rows_at(d, inv_d, inv_r, si, oj, st.sphere_jacobians,
                                    st.sphere_jdqd, st.sphere_jacobians @ self.qd, self.ov)
        return rows, x, jd, xd - rows @ self.qd
