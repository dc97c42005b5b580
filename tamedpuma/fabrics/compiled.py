"""Compiled (numba) kernels of the fabric's hot path: ``fabric.kernel=auto`` (the default:
compiled where numba is installed, the ``fast`` extra) or ``numba``; ``numpy``: the reference.

The same maths as :class:`~tamedpuma.fabrics.fused.LayoutBuffers` (the sphere × obstacle pair
rows of ``barrier_rows``, ``barrier_kernel``, the goal rows of ``goal_rows``) and of
:meth:`~tamedpuma.fabrics.fabric.Fabric.evaluate`'s products, solves and dot products, written as
loops that numba compiles: at a few obstacles the numpy version is ~60 small numpy calls, each
costing more in call overhead than in arithmetic; here they are four. The numpy version stays
the reference: the tests check both against each other (to rounding, ~1e-13 relative: sums are
reassociated, products fused, and the 7 × 7 solves are Gaussian elimination instead of LAPACK's),
and without numba installed (``pip install 'tamedpuma[fast]'``) :data:`AVAILABLE` is False,
``auto`` is the numpy version and asking for ``numba`` is a configuration error. numba is
imported only when the compiled kernels are used. Each kernel compiles for the argument types of
its first call (a few seconds, then from numba's on-disk cache): the methods make that call
when an episode starts (:meth:`~tamedpuma.fabrics.fabric.Fabric.prepare`), never inside a step.

Pair ``(i, j)``, with ``d = c_i − o_j``, ``v = J_i q̇ − ȯ_j``, ``a = J̇_i q̇``, ``R = r_i + r_j``
(leaves.sphere_obstacle_pairs): ``x = ‖d‖/R − 1``, ``ẋ = dᵀv/(‖d‖R)``,
``J̇q̇ = (dᵀa + ‖v‖² − (dᵀv/‖d‖)²)/(‖d‖R)`` and the row ``(d/(‖d‖R))ᵀ J_i``; the clearance
``‖d‖ − R`` [m]. Kernel row r (energy.barrier_leaf), with the per-row constants of
:func:`~tamedpuma.fabrics.fused.kernel_constants`:
``W[c, r] = gain[c, r] · [ẋ_r < threshold[c, r]] · x_r^{negexp[c, r]}``, ``T = W ẋ²`` and the
design matrix's columns ``h + J̇q̇ = T[1] + J̇q̇``, ``κ + J̇q̇ = T[2] + J̇q̇``; returns ``½ Σ T[0]``.
"""

from __future__ import annotations

import importlib.util
from types import SimpleNamespace

import numpy as np

#: numba is installed (the optional ``fast`` extra); it is imported only when a fabric asks for
#: the compiled kernels (importing it costs ~0.5 s), by :func:`kernels`
AVAILABLE = importlib.util.find_spec("numba") is not None
KERNELS = ("auto", "numpy", "numba")
_COMPILED: SimpleNamespace | None = None


def _sphere_velocity(J, qd, i, out):
    """``out = J_i q̇`` (3,) [m/s] of body sphere i."""
    for c in range(3):
        acc = 0.0
        for q in range(qd.shape[0]):
            acc += J[i, c, q] * qd[q]
        out[c] = acc


def _clearance(centers, radii, oc, orad, i, j):
    """``(‖d‖ − R, ‖d‖², R)`` of pair (i, j), ``d = c_i − o_j``, ``R = r_i + r_j`` [m]."""
    d0 = centers[i, 0] - oc[j, 0]
    d1 = centers[i, 1] - oc[j, 1]
    d2 = centers[i, 2] - oc[j, 2]
    dd = max(d0 * d0 + d1 * d1 + d2 * d2, 1e-24)
    big_r = radii[i] + orad[j]
    return dd * (1.0 / np.sqrt(dd)) - big_r, dd, big_r


def _pair_row(centers, J, jdqd, radii, oc, orad, ov, v_s, i, j, z):
    """Pair (i, j) given the sphere's velocity v_s = J_i q̇: writes its Jacobian row
    ``(d/(‖d‖R))ᵀ J_i`` into z (n,) and returns ``(clearance, x, ẋ, J̇q̇)``."""
    clr, dd, big_r = _clearance(centers, radii, oc, orad, i, j)
    d0 = centers[i, 0] - oc[j, 0]
    d1 = centers[i, 1] - oc[j, 1]
    d2 = centers[i, 2] - oc[j, 2]
    v0 = v_s[0] - ov[j, 0]
    v1 = v_s[1] - ov[j, 1]
    v2 = v_s[2] - ov[j, 2]
    dv = d0 * v0 + d1 * v1 + d2 * v2
    da = d0 * jdqd[i, 0] + d1 * jdqd[i, 1] + d2 * jdqd[i, 2]
    vv = v0 * v0 + v1 * v1 + v2 * v2
    inv_d = 1.0 / np.sqrt(dd)
    inv_r = 1.0 / big_r
    w = inv_d * inv_r
    t = dv * inv_d
    u0, u1, u2 = d0 * w, d1 * w, d2 * w
    for q in range(z.shape[0]):
        z[q] = u0 * J[i, 0, q] + u1 * J[i, 1, q] + u2 * J[i, 2, q]
    return clr, clr * inv_r, dv * w, (da + vv - t * t) * w


def _pair_rows(centers, J, jdqd, radii, qd, oc, orad, ov, xp, xdp, jdp, Zp, clear):
    """Fill the pair rows in place: xp, xdp, jdp, clear (k, m) and Zp (k, m, n)."""
    v_s = np.empty(3)
    for i in range(centers.shape[0]):
        _sphere_velocity(J, qd, i, v_s)
        for j in range(oc.shape[0]):
            clear[i, j], xp[i, j], xdp[i, j], jdp[i, j] = _pair_row(
                centers, J, jdqd, radii, oc, orad, ov, v_s, i, j, Zp[i, j])


def _near_pair_rows(centers, J, jdqd, radii, qd, oc, orad, ov, activation, keep_all, x, xd,
                    jd, Z, clear, far):
    """The pair rows of the pairs within the activation distance only (fused.LayoutBuffers.
    _gathered_pair_rows): every pair's clearance (k, m) and far mask ``‖d‖ − R ≥ x_a R``
    (all False when keep_all), then x, ẋ, J̇q̇ and the Jacobian rows of the other pairs, in
    pair order, written to rows ``[lo, P)`` of x, xd, jd and Z (R, n + 2). Returns lo."""
    k, m, n = centers.shape[0], oc.shape[0], qd.shape[0]
    count = 0
    for i in range(k):
        for j in range(m):
            clr, _, big_r = _clearance(centers, radii, oc, orad, i, j)
            clear[i, j] = clr
            f = clr >= activation * big_r and not keep_all
            far[i, j] = f
            if not f:
                count += 1
    lo = k * m - count
    r = lo
    v_s = np.empty(3)
    for i in range(k):
        _sphere_velocity(J, qd, i, v_s)
        for j in range(m):
            if far[i, j]:
                continue
            _, x[r], xd[r], jd[r] = _pair_row(centers, J, jdqd, radii, oc, orad, ov, v_s, i, j,
                                              Z[r, :n])
            r += 1
    return lo


def _power(x, e):
    """``x**e``; for a small negative integer e (the usual barrier exponents) as products of
    ``1/x`` (``pow`` costs more than the rest of a kernel row)."""
    if e == 0.0:
        return 1.0
    if e < 0.0 and e >= -8.0 and e == np.floor(e):
        inv = 1.0 / x
        out = inv
        for _ in range(int(-e) - 1):
            out *= inv
        return out
    return x ** e


def _kernel(x, xd, negexp, gain, threshold, jd, W, T, Zb_hl, n_pairs, activation):
    """Fill W[:, :Rb], T and the design matrix's h and κ columns; return ½ Σ m ẋ². The first
    n_pairs rows (obstacle pairs) take the activation taper (fused.LayoutBuffers._taper_pairs;
    activation = inf: untouched)."""
    energy = 0.0
    for r in range(x.shape[0]):
        xdr = xd[r]
        xd2 = xdr * xdr
        for c in range(3):
            W[c, r] = _power(x[r], negexp[c, r]) * gain[c, r] if xdr < threshold[c, r] else 0.0
        if r < n_pairs and activation < np.inf:
            t = 1.0 - (x[r] / activation) ** 2
            if t > 0.0:
                W[0, r] *= t * t
                W[2, r] -= 2.0 * x[r] / (activation * activation * t)
            else:
                W[0, r] = 0.0
                W[2, r] = 0.0
        for c in range(3):
            T[c, r] = W[c, r] * xd2
        energy += T[0, r]
        Zb_hl[0, r] = T[1, r] + jd[r]
        Zb_hl[1, r] = T[2, r] + jd[r]
    return 0.5 * energy


def _goal_rows(R, J, jdqd, qd, tb, tx, ee_position, goal_position, goal_rotation, Zg, E,
               sq):
    """The goal rows before the attractor's gains (fused.LayoutBuffers.goal_rows): Zg (3K, n+2)
    = ``[a | J̇q̇ | ω × x_k]`` (position block ``[J_v | J̇q̇_v | 0]``, orientation block k
    ``[B_k J_ω | B_k (J̇q̇)_ω + ω × (ω × x_k) | B_k ω]``, ``B_k = −[x_k]×`` from ``tb``), the
    errors E (3K,) (``p − p_g``; ``(R − R_g) a_k`` from ``tx``) and their squared norms sq (K,)."""
    n = qd.shape[0]
    A = tb.shape[0] // 3
    omega = np.zeros(3)
    for c in range(3):
        acc = 0.0
        for q in range(n):
            acc += J[3 + c, q] * qd[q]
        omega[c] = acc
    for c in range(3):  # position block
        for q in range(n):
            Zg[c, q] = J[c, q]
        Zg[c, n] = jdqd[c]
        Zg[c, n + 1] = 0.0
        E[c] = ee_position[c] - goal_position[c]
    sq[0] = E[0] * E[0] + E[1] * E[1] + E[2] * E[2]
    B = np.empty((3, 3))
    for k in range(A):
        for a in range(3):
            row = 3 * k + a
            for b in range(3):
                acc = 0.0
                for e in range(9):
                    acc += tb[row, b, e] * R[e // 3, e % 3]
                B[a, b] = acc
        total = 0.0
        for a in range(3):
            row = 3 + 3 * k + a
            for q in range(n):
                Zg[row, q] = B[a, 0] * J[3, q] + B[a, 1] * J[4, q] + B[a, 2] * J[5, q]
            Zg[row, n] = B[a, 0] * jdqd[3] + B[a, 1] * jdqd[4] + B[a, 2] * jdqd[5]
            Zg[row, n + 1] = B[a, 0] * omega[0] + B[a, 1] * omega[1] + B[a, 2] * omega[2]
            acc = 0.0
            for e in range(9):
                acc += (R[e // 3, e % 3] - goal_rotation[e // 3, e % 3]) * tx[e, row - 3]
            E[row] = acc
            total += acc * acc
        sq[1 + k] = total
        # + ω × (ω × x_k), with ω × x_k = B_k ω the column just written
        y0, y1, y2 = Zg[3 + 3 * k, n + 1], Zg[4 + 3 * k, n + 1], Zg[5 + 3 * k, n + 1]
        Zg[3 + 3 * k, n] += omega[1] * y2 - omega[2] * y1
        Zg[4 + 3 * k, n] += omega[2] * y0 - omega[0] * y2
        Zg[5 + 3 * k, n] += omega[0] * y1 - omega[1] * y0


def _systems_solve(Z, m, Rb, qd, Ms, dots):
    """``Ms[0] = [M | f | f_L | M⁻¹f | (M + M_ψ)⁻¹(f + f_ψ) | q̇]`` and ``Ms[1, :, :n+1] =
    [M + M_ψ | f + f_ψ]`` from the design matrix Z (R, n+2) and row metrics m (R,) (barrier and
    base rows ``[:Rb]``, goal rows after), the two solves by Gaussian elimination with partial
    pivoting, and ``dots = q̇ᵀ Ms[0]`` (fused.LayoutBuffers.systems, then Fabric.evaluate)."""
    n = qd.shape[0]
    R = Z.shape[0]
    for i in range(n):
        for j in range(n + 2):
            Ms[0, i, j] = 0.0
    for r in range(Rb):  # row by row: Σ m_r z_r z_rᵀ over the barrier and base rows
        mr = m[r]
        for i in range(n):
            zi = Z[r, i] * mr
            for j in range(n + 2):
                Ms[0, i, j] += zi * Z[r, j]
    for i in range(n):
        for j in range(n + 1):
            Ms[1, i, j] = Ms[0, i, j]
    for r in range(Rb, R):  # + the goal rows
        mr = m[r]
        for i in range(n):
            zi = Z[r, i] * mr
            for j in range(n + 1):
                Ms[1, i, j] += zi * Z[r, j]
    A = np.empty((n, n + 1))
    for s in range(2):
        for i in range(n):
            for j in range(n + 1):
                A[i, j] = Ms[s, i, j]
        for c in range(n):  # forward elimination with partial pivoting
            p = c
            for i in range(c + 1, n):
                if abs(A[i, c]) > abs(A[p, c]):
                    p = i
            if p != c:
                for j in range(n + 1):
                    A[c, j], A[p, j] = A[p, j], A[c, j]
            for i in range(c + 1, n):
                f = A[i, c] / A[c, c]
                for j in range(c, n + 1):
                    A[i, j] -= f * A[c, j]
        for i in range(n - 1, -1, -1):  # back substitution: Ms[0, :, n + 2 + s] = A⁻¹ b
            acc = A[i, n]
            for j in range(i + 1, n):
                acc -= A[i, j] * Ms[0, j, n + 2 + s]
            Ms[0, i, n + 2 + s] = acc / A[i, i]
    for i in range(n):
        Ms[0, i, n + 4] = qd[i]
    for j in range(n + 5):
        acc = 0.0
        for i in range(n):
            acc += qd[i] * Ms[0, i, j]
        dots[j] = acc


def kernels() -> SimpleNamespace:
    """The compiled kernels ``pair_rows``, ``near_pair_rows``, ``kernel``, ``goal_rows``,
    ``systems_solve`` (numba
    imported and the functions wrapped on the first call; each compiles on its first use, a few
    seconds, then is cached on disk next to this file)."""
    global _COMPILED
    if _COMPILED is None:
        import numba

        # reassociation and contraction (FMA) only: NaN and inf still propagate (non-finite
        # input must reach the caller's check); results move by rounding only
        fast = {"reassoc", "contract"}
        jit = numba.njit(cache=True, nogil=True, fastmath=fast)
        # the kernels call these helpers: compiled, they must find the compiled ones under
        # those names
        for helper in (_power, _sphere_velocity, _clearance, _pair_row):
            globals()[helper.__name__] = numba.njit(cache=True, inline="always",
                                                    fastmath=fast)(helper)
        _COMPILED = SimpleNamespace(pair_rows=jit(_pair_rows), kernel=jit(_kernel),
                                    near_pair_rows=jit(_near_pair_rows),
                                    goal_rows=jit(_goal_rows),
                                    systems_solve=jit(_systems_solve))
    return _COMPILED


def check(kernel_name: str) -> None:
    """Raise ValueError unless ``kernel_name`` is one of :data:`KERNELS` and usable here."""
    if kernel_name not in KERNELS:
        raise ValueError(f"fabric.kernel must be one of {list(KERNELS)}, got {kernel_name!r}")
    if kernel_name == "numba" and not AVAILABLE:
        raise ValueError("fabric.kernel=numba needs numba: pip install 'tamedpuma[fast]'")


def wanted(kernel_name: str) -> bool:
    """Whether ``fabric.kernel`` asks for the compiled kernels: ``numba`` always, ``auto`` where
    numba is installed, ``numpy`` never."""
    return kernel_name == "numba" or (kernel_name == "auto" and AVAILABLE)
