"""A numpy (float64) copy of a trained :class:`PumaNet` for per-control-step inference.

For one state, torch's per-operation overhead dominates (≈ 0.2 ms forward, ≈ 1 ms with autograd);
this copy evaluates the same layers with numpy and back-propagates ψ by hand:

- ``out(x, ẋ) = s ⊙ (φ(ρ(x, ẋ)) − φ(ρ(x_g, 0)))``;
- ``ψ(x) = ‖ρ(x, 0) − y_g‖²`` (with the skip part ``c f`` of the latent), ``∂ψ/∂features`` by
  the chain rule through Linear, LayerNorm
  (``∂h = (∂x̂ − mean ∂x̂ − x̂ mean(∂x̂ x̂))/σ``) and exact GELU (``Φ(u) + u φ(u)``), then to
  ``∂ψ/∂e = ∂ψ/∂f_e / s_p`` and ``∂ψ/∂δθ_k = ⟨∂ψ/∂R, ∂R/∂δθ_k⟩``
  (δθ a world-frame rotation applied as ζ ← exp(δθ) ⊗ ζ), through the rotation-matrix input
  ``R(exp(δθ) ⊗ ζ) = exp([δθ]×) R`` so ``∂R/∂δθ_k = [e_k]× R``.

Tested against the torch network (values and gradients).
"""

from __future__ import annotations

import numpy as np
from scipy.special import erf

from ..robot.rotations import SKEW_GENERATORS, unit_quats_to_matrices
from .network import PumaNet

_SQRT2 = np.sqrt(2.0)
_INV_SQRT_2PI = 1.0 / np.sqrt(2.0 * np.pi)


def _np(t) -> np.ndarray:
    return t.detach().cpu().numpy().astype(np.float64)


class _Lin:
    def __init__(self, m):
        self.w, self.b = _np(m.weight).T.copy(), _np(m.bias)


class _LN:
    def __init__(self, m):
        self.g, self.b, self.eps = _np(m.weight), _np(m.bias), float(m.eps)

    def fwd(self, h):
        mu = h.mean(-1, keepdims=True)
        var = ((h - mu) ** 2).mean(-1, keepdims=True)
        sig = np.sqrt(var + self.eps)
        xh = (h - mu) / sig
        return xh * self.g + self.b, (xh, sig)

    def bwd(self, dn, cache):
        xh, sig = cache
        dx = dn * self.g
        return (dx - dx.mean(-1, keepdims=True) - xh * (dx * xh).mean(-1, keepdims=True)) / sig


def _gelu(u):
    return u * 0.5 * (1.0 + erf(u / _SQRT2))


def _dgelu(u):
    return 0.5 * (1.0 + erf(u / _SQRT2)) + u * _INV_SQRT_2PI * np.exp(-0.5 * u * u)


_HAT = SKEW_GENERATORS.reshape(3, 3, 3)  # [e_k]×


class FastNet:
    """Numpy evaluation of a PumaNet's encoder, decoder and potential (see module docstring)."""

    def __init__(self, net: PumaNet):
        e, d = net.encoder, net.decoder
        self.spec = net.spec
        self.e1, self.n1, self.e2 = _Lin(e[0]), _LN(e[1]), _Lin(e[3])
        self.n2, self.e3 = _LN(e[4]), _Lin(e[6])
        self.d0, self.d1, self.d2, self.d3 = _LN(d[0]), _Lin(d[1]), _Lin(d[3]), _Lin(d[5])
        self.pos_scale, self.vel_scale = _np(net.pos_scale), _np(net.vel_scale)
        self.out_scale = _np(net.out_scale)
        self.pin_goal = net.cfg.pin_goal
        self.skip = float(net.cfg.skip)
        n = self.spec.n_pos
        self._zero_vel = np.zeros(self.spec.tangent_dim)
        goal = np.zeros(n + (4 if self.spec.orientation else 0))
        if self.spec.orientation:
            goal[n + 3] = 1.0
        self.y_goal = self._encode_features(self._features(goal[None, :n], goal[None, n:] if
                                                           self.spec.orientation else None,
                                                           None))[0]
        self.goal_out = self._decode(self.y_goal[None])[0] if self.pin_goal else 0.0

    def _features(self, pos, quat, vel):
        parts = [pos / self.pos_scale]
        if self.spec.orientation:
            parts.append(unit_quats_to_matrices(quat).reshape(quat.shape[:-1] + (9,)))
        if self.spec.order == 2:
            parts.append((vel if vel is not None else np.zeros(pos.shape[:-1] + (
                self.spec.tangent_dim,))) / self.vel_scale)
        return np.concatenate(parts, axis=-1)

    def _encode_features(self, f, keep=False):
        h1 = f @ self.e1.w + self.e1.b
        n1, c1 = self.n1.fwd(h1)
        a1 = _gelu(n1)
        h2 = a1 @ self.e2.w + self.e2.b
        n2, c2 = self.n2.fwd(h2)
        a2 = _gelu(n2)
        y = a2 @ self.e3.w + self.e3.b
        if self.skip > 0:
            y = np.concatenate((y, self.skip * f), axis=-1)
        return (y, (n1, c1, n2, c2)) if keep else y

    def _decode(self, y):
        u, _ = self.d0.fwd(y)
        h = _gelu(u @ self.d1.w + self.d1.b)
        h = _gelu(h @ self.d2.w + self.d2.b)
        return h @ self.d3.w + self.d3.b

    def forward(self, pos, quat=None, vel=None) -> np.ndarray:
        """Acceleration (order 2) or velocity (order 1), physical units, (B, tangent)."""
        y = self._encode_features(self._features(pos, quat, vel))
        return (self._decode(y) - self.goal_out) * self.out_scale

    def encode(self, pos, quat=None, vel=None) -> np.ndarray:
        return self._encode_features(self._features(pos, quat, vel))

    def potential(self, pos, quat=None):
        """``(ψ (B,), ∂ψ/∂e (B, n), ∂ψ/∂δθ (B, 3) | None)`` at rest."""
        f = self._features(pos, quat, None)
        y, (n1, c1, n2, c2) = self._encode_features(f, keep=True)
        diff = y - self.y_goal
        psi = (diff * diff).sum(-1)
        z = self.e3.w.shape[1]
        g = (2.0 * diff[..., :z]) @ self.e3.w.T
        g = self.n2.bwd(g * _dgelu(n2), c2) @ self.e2.w.T
        g = self.n1.bwd(g * _dgelu(n1), c1) @ self.e1.w.T  # ∂ψ/∂features
        if self.skip > 0:
            g = g + 2.0 * self.skip * diff[..., z:]
        n = self.spec.n_pos
        dpos = g[..., :n] / self.pos_scale
        if not self.spec.orientation:
            return psi, dpos, None
        # R(exp(δθ) ⊗ ζ) = exp([δθ]×) R(ζ): ∂R/∂δθ_k = [e_k]× R
        gR = g[..., n:n + 9].reshape(-1, 3, 3)
        dR = np.einsum("kij,bjl->bkil", _HAT, unit_quats_to_matrices(quat))
        dtheta = np.einsum("bkil,bil->bk", dR, gR)
        return psi, dpos, dtheta
