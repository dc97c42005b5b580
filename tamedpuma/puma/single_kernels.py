"""The one-state network's three passes (:class:`~tamedpuma.puma.single.SingleState`: encoder,
decoder, ψ's backward pass) as numba kernels: one compiled call each instead of ~10 numpy calls,
whose per-call overhead (~1-2 µs each) is most of a one-state evaluation at width 128.

The same maths as SingleState's numpy path, which stays the reference (the tests hold the two to
1e-12 relative): the products are numba's calls of the same BLAS routines (one row at a time
instead of a batch of one or two), the normal CDF is ``Φ(u) = ½ erfc(−u/√2)`` as scipy's
``ndtr`` computes it but with the C library's ``erf``/``erfc`` instead of Cephes', and the
decoder's mean is a plain sum (numpy's is pairwise): the last bits may differ.

Two more kernels serve the control step of a pose net from one packed vector (p, ζ, p_g, ζ_g,
v, ω): :func:`forward_pose` (the goal-relative pose, the input rows, encoder and decoder) and
:func:`potential_pose` (the pose, the rest-row check, the backward pass and the pull to the
joints). They give the compiled passes' numbers bit for bit: the pose is the Python-float
arithmetic of puma/primitive.py operation for operation, and the products are ``np.dot`` on the
shapes and layouts numpy's calls take.

:func:`kernels` compiles them (a few seconds, then from numba's on-disk cache) when a network
is loaded, never inside a control step; None where numba is not installed or fails to compile
(then SingleState stays on its numpy path).
"""

from __future__ import annotations

import importlib.util
import math
from types import SimpleNamespace

import numpy as np

#: numba is installed (the ``fast`` extra)
AVAILABLE = importlib.util.find_spec("numba") is not None
_SQRT1_2 = 0.7071067811865476  # 1/√2, as scipy's ndtr (NPY_SQRT1_2)
_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_COMPILED: list = []  # [namespace or None] once tried


def _ndtr(u, out):
    """``out = Φ(u)`` elementwise, by scipy's ``ndtr`` branches."""
    for i in range(u.shape[0]):
        x = u[i] * _SQRT1_2
        z = abs(x)
        if z < _SQRT1_2:
            out[i] = 0.5 + 0.5 * math.erf(x)
        else:
            y = 0.5 * math.erfc(z)
            out[i] = 1.0 - y if x > 0.0 else y


def _ln_gelu(c, u, t, a, g, b, eps):
    """One row, in place: ``σ = √(c·c/w + ε)``, ``c ← x̂ = c/σ``, ``u = x̂γ + β``, ``t = Φ(u)``,
    ``a[:w] = u t`` (GELU); returns σ."""
    w = c.shape[0]
    s = math.sqrt(np.dot(c, c) / w + eps)
    inv = 1.0 / s
    for k in range(w):
        c[k] *= inv
        u[k] = c[k] * g[k] + b[k]
    _ndtr(u, t)
    for k in range(w):
        a[k] = u[k] * t[k]
    return s


def encode(f, W1, g1, b1, eps1, W2, g2, b2, eps2, W3, skip, c1, u1, t1, a1, c2, u2, t2, a2,
           y, sig):
    """SingleState._encode for every row of f (B, d + 1): fills the row buffers (x̂ in c, u, Φ(u)
    in t, GELU in a), the latent y = [ρ_net(f), skip f] and the LayerNorms' σ in sig (B, 2)."""
    z = W3.shape[1]
    for r in range(f.shape[0]):
        c1[r, :] = np.dot(f[r], W1)
        sig[r, 0] = _ln_gelu(c1[r], u1[r], t1[r], a1[r], g1, b1, eps1)
        c2[r, :] = np.dot(a1[r], W2)
        sig[r, 1] = _ln_gelu(c2[r], u2[r], t2[r], a2[r], g2, b2, eps2)
        y[r, :z] = np.dot(a2[r], W3)
        if skip > 0.0:
            for k in range(f.shape[1] - 1):
                y[r, z + k] = f[r, k] * skip


def decode(y, D1, D2, D3, eps0, h, t):
    """SingleState._decode: ``(φ(y) − φ_g) ⊙ s_out`` of the latent y (h: the hidden buffer with
    its trailing 1, t: width scratch)."""
    n = y.shape[0]
    w = t.shape[0]
    mean = 0.0
    for k in range(n):
        mean += y[k]
    mean /= n
    c = y - mean
    sig = math.sqrt(np.dot(c, c) / n + eps0)
    c *= 1.0 / sig
    u = np.dot(c, D1[:-1])
    for k in range(w):
        u[k] += D1[-1, k]
    _ndtr(u, t)
    for k in range(w):
        h[k] = u[k] * t[k]
    u = np.dot(h, D2)
    _ndtr(u, t)
    for k in range(w):
        h[k] = u[k] * t[k]
    return np.dot(h, D3)


def _ln_back(g, xh, u, t, gam, sig, WT):
    """∂ψ through one GELU(LayerNorm(·)) layer and its centred weights (SingleState._backward)."""
    w = g.shape[0]
    for k in range(w):
        uk = u[k]
        g[k] *= (math.exp(-0.5 * (uk * uk)) * uk * _INV_SQRT_2PI + t[k]) * gam[k]
    proj = np.dot(g, xh) / w
    for k in range(w):
        g[k] -= xh[k] * proj
    out = np.dot(g, WT)
    out *= 1.0 / sig
    return out


def backward(y, y_goal, e3T, xh2, u2, t2, g2, sig2, e2T, xh1, u1, t1, g1, sig1, e1T, skip):
    """SingleState._backward of one row at rest: ``(ψ, ∂ψ/∂f)`` from its forward caches."""
    z = e3T.shape[0]
    diff = y - y_goal
    psi = np.dot(diff, diff)
    g = np.dot(diff[:z], e3T)
    g *= 2.0
    g = _ln_back(g, xh2, u2, t2, g2, sig2, e2T)
    g = _ln_back(g, xh1, u1, t1, g1, sig1, e1T)
    if skip > 0.0:
        for k in range(diff.shape[0] - z):
            g[k] += (2.0 * skip) * diff[z + k]
    return psi, g


def _inv_norm(sq):
    """1/√sq; NaN for a zero (or NaN) squared norm (robot/rotations.py ``_inv_norm``)."""
    if sq > 0.0:
        return 1.0 / math.sqrt(sq)
    return math.nan


def pose_row(x, row):
    """The goal-relative pose of the packed state x (p (3), ζ (4), p_g (3), ζ_g (4), …) into
    ``row[:12]``: ``p − p_g`` [m], then the row-major entries of R(ζ ⊗ ζ_g⁻¹), both quaternions
    normalised first; the Python-float arithmetic of puma/primitive.py ``_pose_error``
    (robot/rotations.py ``relative_rotation``), operation for operation."""
    for k in range(3):
        row[k] = x[k] - x[7 + k]
    ax, ay, az, aw = x[3], x[4], x[5], x[6]
    na = _inv_norm(ax * ax + ay * ay + az * az + aw * aw)
    ax, ay, az, aw = ax * na, ay * na, az * na, aw * na
    bx, by, bz, bw = x[10], x[11], x[12], x[13]
    nb = _inv_norm(bx * bx + by * by + bz * bz + bw * bw)
    bx, by, bz, bw = -bx * nb, -by * nb, -bz * nb, bw * nb
    qx = aw * bx + ax * bw + ay * bz - az * by  # the Hamilton product a ⊗ b
    qy = aw * by - ax * bz + ay * bw + az * bx
    qz = aw * bz + ax * by - ay * bx + az * bw
    qw = aw * bw - ax * bx - ay * by - az * bz
    row[3] = 1 - 2 * (qy * qy + qz * qz)
    row[4] = 2 * (qx * qy - qz * qw)
    row[5] = 2 * (qx * qz + qy * qw)
    row[6] = 2 * (qx * qy + qz * qw)
    row[7] = 1 - 2 * (qx * qx + qz * qz)
    row[8] = 2 * (qy * qz - qx * qw)
    row[9] = 2 * (qx * qz - qy * qw)
    row[10] = 2 * (qy * qz + qx * qw)
    row[11] = 1 - 2 * (qx * qx + qy * qy)


def forward_pose(x, rest, raw, s_in, f, W1, g1, b1, eps1, W2, g2, b2, eps2, W3, skip, c1, u1,
                 t1, a1, c2, u2, t2, a2, y, sig, D1, D2, D3, eps0, h, t):
    """SingleState.forward of a second-order pose net in one call, from the packed state
    x = (p, ζ, p_g, ζ_g, v, ω) (20,) [m, 1, m, 1, m/s, rad/s]: row 0 of raw the goal-relative
    pose (:func:`pose_row`) and the twist; with ``rest`` row 1 the same pose at rest; then
    ``f = raw ⊙ s_in``, :func:`encode` and :func:`decode` of row 0: the acceleration
    ``[a; α]`` (6,) [m/s², rad/s²]."""
    row = raw[0]
    pose_row(x, row)
    for k in range(6):
        row[12 + k] = x[14 + k]
    B = 1
    if rest:
        B = 2
        for k in range(12):
            raw[1, k] = row[k]
        for k in range(12, 18):
            raw[1, k] = 0.0
    for r in range(B):
        for k in range(raw.shape[1]):
            f[r, k] = raw[r, k] * s_in[k]
    encode(f, W1, g1, b1, eps1, W2, g2, b2, eps2, W3, skip, c1, u1, t1, a1, c2, u2, t2, a2, y,
           sig)
    return decode(y[0], D1, D2, D3, eps0, h, t)


def potential_pose(x, memo, raw2, c1_2, u1_2, t1_2, c2_2, u2_2, t2_2, y2, sig2, raw, s_in, f, W1,
                   g1, b1, eps1, W2, g2, b2, eps2, W3, skip, c1, u1, t1, a1, c2, u2, t2, a2, y, sig,
                   y_goal, e3T, e2T, e1T, pos_scale, jac):
    """SingleState.potential of a pose net and PoseTask's pull to the joints in one call, from
    the packed state x = (p, ζ, p_g, ζ_g, …): the goal-relative pose (:func:`pose_row`); where
    ``memo`` and it equals the rest row of the last forward pass (row 1 of raw2 and the other
    B = 2 buffers), that row's caches, else the pose at rest encoded in the B = 1 buffers;
    :func:`backward`; ``∂ψ/∂e = g/s_pos``, ``∂ψ/∂δθ = vee(A − Aᵀ)`` with ``A = G Rᵀ``; and
    ``∂ψ/∂q = ∂ψ/∂e · J_v + ∂ψ/∂δθ · J_ω`` (jac (6, n) the hand's world-aligned Jacobian):
    (ψ, ∂ψ/∂q (n,))."""
    pose = np.empty(12)
    pose_row(x, pose)
    same = memo
    if memo:
        for k in range(12):
            if not pose[k] == raw2[1, k]:
                same = False
    if same:
        R = raw2[1, 3:12].reshape(3, 3)
        psi, g = backward(y2[1], y_goal, e3T, c2_2[1], u2_2[1], t2_2[1], g2, sig2[1, 1], e2T,
                          c1_2[1], u1_2[1], t1_2[1], g1, sig2[1, 0], e1T, skip)
    else:
        row = raw[0]
        for k in range(12):
            row[k] = pose[k]
        for k in range(12, raw.shape[1] - 1):
            row[k] = 0.0
        for k in range(raw.shape[1]):
            f[0, k] = row[k] * s_in[k]
        encode(f, W1, g1, b1, eps1, W2, g2, b2, eps2, W3, skip, c1, u1, t1, a1, c2, u2, t2, a2, y,
               sig)
        R = raw[0, 3:12].reshape(3, 3)
        psi, g = backward(y[0], y_goal, e3T, c2[0], u2[0], t2[0], g2, sig[0, 1], e2T, c1[0],
                          u1[0], t1[0], g1, sig[0, 0], e1T, skip)
    dpos = g[:3] / pos_scale
    a = np.dot(g[3:12].reshape(3, 3), R.T).ravel()
    dtheta = np.array([a[7] - a[5], a[2] - a[6], a[3] - a[1]])
    return psi, np.dot(dpos, jac[:3]) + np.dot(dtheta, jac[3:])


def kernels() -> SimpleNamespace | None:
    """encode, decode and backward compiled (once per process; None without numba or where it
    fails, with a warning)."""
    from tamedpuma.jit import compile_once

    return compile_once(_COMPILED, _compile, AVAILABLE, "the network's kernels",
                        "one-state evaluations use numpy")


def _compile() -> SimpleNamespace:
    """The kernels compiled, calling compiled copies of the helpers (the module's functions stay
    plain)."""
    from tamedpuma.jit import compile_kernels

    return SimpleNamespace(**compile_kernels(globals(), (encode, decode, backward, forward_pose,
                                                               potential_pose),
                                             (_ndtr, _ln_gelu, _ln_back, _inv_norm, pose_row,
                                              encode, decode, backward)))
