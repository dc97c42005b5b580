"""The PUMA network for one state per call: the control loop's path (numpy, float64).

Same maths as :class:`~tamedpuma.puma.fastnet.FastNet` (the batched numpy reference, itself tested
against the torch network), rearranged so that one evaluation is a fixed, small number of numpy
calls on preallocated buffers (for one state the time is per-call overhead, not arithmetic):

- constants folded into the weights once: the input normalisation ``f = x ⊙ s_in`` (kept for the
  skip part of the latent), each LayerNorm's centring ``h − mean(h) = f (W − W̄) + (b − b̄)``
  (W̄ the row means), the decoder's LayerNorm gain and bias
  ``(x̂ ⊙ γ + β) W + b = x̂ (γ ⊙ W) + (β W + b)`` and the output ``(φ − φ_g) ⊙ s_out``; every bias
  rides in a trailing 1 of the layer's input;
- exact GELU as ``u Φ(u)`` with the normal CDF ``Φ(u) = ½(1 + erf(u/√2))`` (scipy's ``ndtr``, one
  call) and its derivative ``Φ(u) + u e^{−u²/2}/√(2π)``;
- the rotation matrix of ``ζ ⊗ ζ_g⁻¹`` from Python floats, not array calls;
- ψ's gradient by hand (as FastNet), and the world-frame rotation part
  ``∂ψ/∂δθ_k = ⟨[e_k]× R, G⟩ = vee(A − Aᵀ)_k`` with ``A = G Rᵀ`` (G = ∂ψ/∂R);
- once :meth:`potential` has been asked for (CPM), every :meth:`forward` also encodes the state at
  rest ``(x, 0)`` as a second row of the same products, and :meth:`potential` at that same pose
  reuses it (only the backward pass is left): ψ costs CPM a few calls, not a second network pass.

Tested against FastNet and against the torch network in float64 (1e-10). Where numba is
installed the encoder, decoder and backward pass each run as one compiled call
(:mod:`~tamedpuma.puma.single_kernels`, the numbers of this module's numpy path to 1e-12), and
a pose net's control step calls :meth:`SingleState.forward_packed` and
:meth:`SingleState.potential_packed`: each one compiled call from a packed state, the numbers of
the listed calls bit for bit.
"""

from __future__ import annotations

import copy
import math

import numpy as np
from scipy.special import ndtr

from . import single_kernels
from .fastnet import FastNet

_INV_SQRT_2PI = 1.0 / math.sqrt(2.0 * math.pi)
_dot = np.dot
_add, _mul, _sub = np.add, np.multiply, np.subtract


def _centred(w: np.ndarray, b: np.ndarray) -> np.ndarray:
    """``[[W − W̄], [b − b̄]]`` (in + 1, out): a linear layer whose output has zero mean."""
    return np.vstack((w - w.mean(axis=1, keepdims=True), (b - b.mean())[None]))


class _Rows:
    """Buffers of one batch size B (1: the state; 2: the state and the same pose at rest)."""

    def __init__(self, B: int, d: int, w: int, z: int, skip: bool):
        self.f = np.ones((B, d + 1))  # normalised input and the bias 1
        self.raw = np.ones((B, d + 1))
        self.c1, self.c2 = np.empty((B, w)), np.empty((B, w))
        self.a1, self.a2 = np.ones((B, w + 1)), np.ones((B, w + 1))
        self.t1, self.t2 = np.empty((B, w)), np.empty((B, w))
        self.u1, self.u2 = np.empty((B, w)), np.empty((B, w))
        self.y = np.empty((B, z + (d if skip else 0)))
        self.sig = np.empty((B, 2))  # the two LayerNorms' σ per row (compiled path)


class SingleState:
    """One-state evaluation of a :class:`FastNet` (see the module docstring). Not thread-safe.
    compiled: the encoder, decoder and backward pass as numba kernels
    (:mod:`~tamedpuma.puma.single_kernels`, the same numbers to rounding) where numba is
    installed; False: this module's numpy path, the reference."""

    def __init__(self, fast: FastNet, compiled: bool = True):
        spec = self.spec = fast.spec
        self.n = spec.n_pos
        self.ori = spec.orientation
        self.order = spec.order
        self.d = spec.input_dim
        self.w = fast.e1.w.shape[1]
        self.z = fast.e3.w.shape[1]
        self.skip = fast.skip
        s_in = [1.0 / np.asarray(fast.pos_scale, float).reshape(-1) * np.ones(self.n)]
        if self.ori:
            s_in.append(np.ones(9))
        if self.order == 2:
            s_in.append(1.0 / np.asarray(fast.vel_scale, float).reshape(-1)
                        * np.ones(spec.tangent_dim))
        self.s_in = np.concatenate(s_in + [np.ones(1)])
        # encoder: centred layers 1 and 2 (their LayerNorms' means folded in)
        self.W1 = _centred(fast.e1.w, fast.e1.b)
        self.W2 = _centred(fast.e2.w, fast.e2.b)
        self.W3 = np.vstack((fast.e3.w, fast.e3.b[None]))
        self.g1, self.b1, self.eps1 = fast.n1.g, fast.n1.b, fast.n1.eps
        self.g2, self.b2, self.eps2 = fast.n2.g, fast.n2.b, fast.n2.eps
        # decoder: LayerNorm gain/bias folded into d1; output (φ − φ_g) ⊙ s_out folded into d3
        d0 = fast.d0
        self.eps0 = d0.eps
        self.D1 = np.vstack((d0.g[:, None] * fast.d1.w, (d0.b @ fast.d1.w + fast.d1.b)[None]))
        self.D2 = np.vstack((fast.d2.w, fast.d2.b[None]))
        out_scale = np.asarray(fast.out_scale, float).reshape(-1)
        self.D3 = np.vstack((fast.d3.w, (fast.d3.b - fast.goal_out)[None])) * out_scale
        # ψ: the goal latent, and the weights of the backward pass: the centred ones for the
        # layers followed by a LayerNorm, whose backward centring they make redundant
        # (W̄ = row means: (g − mean g) (W − W̄1ᵀ)ᵀ = g (W − W̄1ᵀ)ᵀ and Σ(LayerNorm grad) = 0)
        self.y_goal = np.array(fast.y_goal, dtype=float)
        self.e3T = fast.e3.w.T.copy()
        self.e2T, self.e1T = self.W2[:-1].T.copy(), self.W1[:-1].T.copy()
        self.pos_scale = np.asarray(fast.pos_scale, float).reshape(-1)
        self.kernels = single_kernels.kernels() if compiled else None
        self._new_buffers()
        if self.kernels is not None:  # compiled (or loaded) for these arrays now, not in a step
            zero = [0.0] * self.n
            rot = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] if self.ori else None
            vel = [0.0] * spec.tangent_dim if self.order == 2 else None
            self.potential(zero, rot)
            self.forward(zero, rot, vel)
            if self.ori and self.order == 2:  # x: the packed state at the goal, at rest
                x = np.array([0.0] * 6 + [1.0] + [0.0] * 6 + [1.0] + [0.0] * 6)
                self.potential_packed(x[:14].copy(), np.zeros((6, self.n)))
                self.forward_packed(x)
                self.potential_packed(x[:14].copy(), np.zeros((6, self.n)))
            self._new_buffers()

    def _new_buffers(self) -> None:
        """The buffers and the memo the calls write (everything else is fixed by __init__)."""
        d, w, z = self.d, self.w, self.z
        self._rows = {B: _Rows(B, d, w, z, self.skip > 0) for B in (1, 2)}
        self._h = np.ones(w + 1)  # decoder hidden, with the bias 1
        self._t = np.empty(w)
        self.want_rest = False  # set by the first potential(): forward then encodes (x, 0) too
        self._rest_key: list | None = None  # pose of the cached rest row
        self._rest: tuple | None = None

    def fresh(self) -> SingleState:
        """A copy sharing the (read-only) weights, with its own buffers and memo, as built:
        one episode's evaluator (``PosePrimitive.for_episode``)."""
        own = copy.copy(self)
        own._new_buffers()
        return own

    # ------------------------------------------------------------------ pieces

    @staticmethod
    def _ln_gelu(c, u, t, a, g, b, eps, width):
        """In place: ``a[:, :w] = gelu(u)`` with ``u = x̂ ⊙ γ + β``, x̂ = c/σ (c centred,
        overwritten by x̂), ``t = Φ(u)``; returns σ per row."""
        sig = []
        for row in c:  # one or two rows: Python floats are cheaper than (B,)-array calls
            s = math.sqrt(float(_dot(row, row)) / width + eps)
            row *= 1.0 / s  # x̂
            sig.append(s)
        _mul(c, g, out=u)
        u += b  # u = x̂γ + β
        ndtr(u, out=t)  # Φ(u)
        _mul(u, t, out=a[:, :width])  # gelu(u) = u Φ(u)
        return sig

    def _encode(self, rows: _Rows):
        """Encoder of every row of rows.f; fills rows.y = [ρ_net(f), c f] and the caches of the
        backward pass (x̂ in c, GELU inputs u, Φ(u) in t); returns the LayerNorms' σ per row."""
        if self.kernels is not None:
            self.kernels.encode(rows.f, self.W1, self.g1, self.b1, self.eps1, self.W2, self.g2,
                                self.b2, self.eps2, self.W3, float(self.skip), rows.c1, rows.u1,
                                rows.t1, rows.a1, rows.c2, rows.u2, rows.t2, rows.a2, rows.y,
                                rows.sig)
            return rows.sig[:, 0], rows.sig[:, 1]
        w = self.w
        _dot(rows.f, self.W1, out=rows.c1)
        s1 = self._ln_gelu(rows.c1, rows.u1, rows.t1, rows.a1, self.g1, self.b1, self.eps1, w)
        _dot(rows.a1, self.W2, out=rows.c2)
        s2 = self._ln_gelu(rows.c2, rows.u2, rows.t2, rows.a2, self.g2, self.b2, self.eps2, w)
        z = self.z
        np.matmul(rows.a2, self.W3, out=rows.y[:, :z])
        if self.skip > 0:
            _mul(rows.f[:, :-1], self.skip, out=rows.y[:, z:])
        return s1, s2

    def _decode(self, y) -> np.ndarray:
        """Fresh output ``(φ(y) − φ_g) ⊙ s_out`` (tangent,) for one latent y."""
        if self.kernels is not None:
            return self.kernels.decode(y, self.D1, self.D2, self.D3, self.eps0, self._h, self._t)
        c = y - _add.reduce(y) / y.shape[0]
        sig = math.sqrt(float(_dot(c, c)) / y.shape[0] + self.eps0)
        c *= 1.0 / sig
        h, t, w = self._h, self._t, self.w
        u = h[:w]
        _dot(c, self.D1[:-1], out=u)
        u += self.D1[-1]
        ndtr(u, out=t)
        u *= t  # gelu
        _dot(h, self.D2, out=t)
        u[:] = t
        ndtr(t, out=t)
        u *= t  # gelu
        return _dot(h, self.D3)

    def _pose_entries(self, e, rot) -> list:
        return [*e, *rot] if self.ori else list(e)

    def _backward(self, rows: _Rows, i: int, sig1, sig2):
        """``(ψ, ∂ψ/∂f)`` of row i (a state at rest) from its forward caches."""
        if self.kernels is not None:
            psi, g = self.kernels.backward(rows.y[i], self.y_goal, self.e3T, rows.c2[i],
                                           rows.u2[i], rows.t2[i], self.g2, float(sig2[i]),
                                           self.e2T, rows.c1[i], rows.u1[i], rows.t1[i], self.g1,
                                           float(sig1[i]), self.e1T, float(self.skip))
            return float(psi), g
        z = self.z
        diff = rows.y[i] - self.y_goal
        psi = float(_dot(diff, diff))
        g = _dot(diff[:z], self.e3T)
        g *= 2.0
        for c, u, t, gam, sig, WT in ((rows.c2, rows.u2, rows.t2, self.g2, sig2, self.e2T),
                                      (rows.c1, rows.u1, rows.t1, self.g1, sig1, self.e1T)):
            xh, u = c[i], u[i]
            # d gelu/du = Φ(u) + u e^{−u²/2}/√(2π) (Φ(u) in t), times γ: ∂ψ/∂x̂
            dg = u * u
            dg *= -0.5
            np.exp(dg, out=dg)
            dg *= u
            dg *= _INV_SQRT_2PI
            dg += t[i]
            g *= dg
            g *= gam
            # LayerNorm: ∂h = (∂x̂ − mean ∂x̂ − x̂ mean(∂x̂ x̂))/σ; mean ∂x̂ vanishes in the
            # product with the centred weights
            g -= xh * (float(_dot(g, xh)) / self.w)
            g = _dot(g, WT)
            g *= 1.0 / sig[i]
        if self.skip > 0:
            g += (2.0 * self.skip) * diff[z:]
        return psi, g

    # ------------------------------------------------------------------ API

    def forward(self, e, rot, vel) -> np.ndarray:
        """Acceleration (order 2) or velocity (order 1) (tangent,) at the goal-relative state:
        e (n,) position error, rot the 9 entries of R(ζ ⊗ ζ_g⁻¹) (pose nets; else None), vel
        (tangent,) (order 2; else None)."""
        pose = self._pose_entries(e, rot)
        rest = self.want_rest and self.order == 2
        rows = self._rows[2 if rest else 1]
        k = len(pose)
        raw = rows.raw
        raw[0, :k] = pose
        if self.order == 2:
            raw[0, k:-1] = vel
        if rest:
            raw[1, :k] = pose
            raw[1, k:-1] = 0.0
        _mul(raw, self.s_in, out=rows.f)
        s1, s2 = self._encode(rows)
        if rest:
            self._rest_key, self._rest = pose, (rows, s1, s2)
        return self._decode(rows.y[0])

    def forward_packed(self, x: np.ndarray) -> np.ndarray | None:
        """:meth:`forward` of a second-order pose net from the packed world-frame state
        x = (p, ζ, p_g, ζ_g, v, ω) (20,) float64 [m, 1, m, 1, m/s, rad/s], in one compiled call
        (:func:`~tamedpuma.puma.single_kernels.forward_pose`: the goal-relative pose of
        puma/primitive.py ``_pose_error`` and :meth:`forward`'s passes, the same arithmetic):
        the acceleration ``[a; α]`` (6,) [m/s², rad/s²]; None where that call does not apply
        (no compiled kernels, not a second-order pose net, x not float64)."""
        if self.kernels is None or not self.ori or self.order != 2 or x.dtype != np.float64:
            return None
        rest = self.want_rest
        rows = self._rows[2 if rest else 1]
        out = self.kernels.forward_pose(x, rest, rows.raw, self.s_in, rows.f, self.W1, self.g1,
                                        self.b1, self.eps1, self.W2, self.g2, self.b2,
                                        self.eps2, self.W3, float(self.skip), rows.c1, rows.u1,
                                        rows.t1, rows.a1, rows.c2, rows.u2, rows.t2, rows.a2,
                                        rows.y, rows.sig, self.D1, self.D2, self.D3, self.eps0,
                                        self._h, self._t)
        if rest:  # the memo :meth:`forward` keeps: the pose entries as floats, the σ's views
            self._rest_key = rows.raw[1, :self.n + 9].tolist()
            self._rest = (rows, rows.sig[:, 0], rows.sig[:, 1])
        return out

    def potential_packed(self, x: np.ndarray, jac: np.ndarray) -> tuple[float, np.ndarray] | None:
        """``(ψ, ∂ψ/∂q (n,))`` of a pose net from the packed state x = (p, ζ, p_g, ζ_g) (14,)
        and the hand's world-aligned Jacobian jac (6, n) in one compiled call
        (:func:`~tamedpuma.puma.single_kernels.potential_pose`): :meth:`potential`'s numbers
        pulled to the joints as PoseTask.potential pulls them, the same arithmetic; None where
        that call does not apply (no compiled kernels, not a pose net, not float64)."""
        if (self.kernels is None or not self.ori or x.dtype != np.float64
                or jac.dtype != np.float64):
            return None
        self.want_rest = True
        rest, one = self._rows[2], self._rows[1]
        psi, grad = self.kernels.potential_pose(
            x, self._rest is not None, rest.raw, rest.c1, rest.u1, rest.t1, rest.c2, rest.u2,
            rest.t2, rest.y, rest.sig, one.raw, self.s_in, one.f, self.W1, self.g1, self.b1,
            self.eps1, self.W2, self.g2, self.b2, self.eps2, self.W3, float(self.skip), one.c1,
            one.u1, one.t1, one.a1, one.c2, one.u2, one.t2, one.a2, one.y, one.sig, self.y_goal,
            self.e3T, self.e2T, self.e1T, self.pos_scale, jac)
        self._rest = None  # the caches are overwritten by the next call
        return float(psi), grad

    def psi(self, e, rot) -> float:
        """ψ alone at the goal-relative pose (e, rot as :meth:`forward`), at rest: one encoder
        pass, no gradient. Unlike :meth:`potential` it leaves :meth:`forward` as it is (no
        second row at rest), so a caller that logs ψ does not slow the control step."""
        pose = self._pose_entries(e, rot)
        if self._rest is not None and pose == self._rest_key:
            y = self._rest[0].y[1]
        else:
            rows, k = self._rows[1], len(pose)
            rows.raw[0, :k] = pose
            rows.raw[0, k:-1] = 0.0
            _mul(rows.raw, self.s_in, out=rows.f)
            self._encode(rows)
            y = rows.y[0]
        diff = y - self.y_goal
        return float(_dot(diff, diff))

    def potential(self, e, rot) -> tuple[float, np.ndarray, np.ndarray | None]:
        """``(ψ, ∂ψ/∂e (n,), ∂ψ/∂δθ (3,) | None)`` at rest, δθ a world-frame rotation applied
        as ζ ← exp(δθ) ⊗ ζ (pose nets)."""
        self.want_rest = True
        pose = self._pose_entries(e, rot)
        if self._rest is not None and pose == self._rest_key:
            rows, s1, s2 = self._rest
            i = 1
        else:
            rows, k = self._rows[1], len(pose)
            rows.raw[0, :k] = pose
            rows.raw[0, k:-1] = 0.0
            _mul(rows.raw, self.s_in, out=rows.f)
            s1, s2 = self._encode(rows)
            i = 0
        self._rest = None  # the caches are overwritten by the next call
        psi, g = self._backward(rows, i, s1, s2)
        n = self.n
        dpos = g[:n] / self.pos_scale
        if not self.ori:
            return psi, dpos, None
        # A = G Rᵀ (G = ∂ψ/∂R, R the input rotation); ∂ψ/∂δθ = vee(A − Aᵀ)
        a = _dot(g[n:n + 9].reshape(3, 3), rows.raw[i, n:n + 9].reshape(3, 3).T).ravel().tolist()
        return psi, dpos, np.array([a[7] - a[5], a[2] - a[6], a[3] - a[1]])
