"""The PUMA network ``ẍ = φ_θ(ρ_θ(x, ẋ))`` (or ``ẋ = φ_θ(ρ_θ(x))`` for a first-order primitive).

State relative to the goal: position ``e = p − p_g`` ∈ Rⁿ [m, or the data's unit], optionally the
orientation ``ζ ⊗ ζ_g⁻¹`` ∈ S³ (x, y, z, w), and for a second-order primitive the velocity
``(ė, ω)`` (ω world-frame [rad/s]). The output lives in the tangent space: ``(ë, ω̇)`` [m/s², rad/s²]
(second order) or ``(ė, ω)`` (first order).

The orientation enters the network as the 9 entries of its rotation matrix R(ζ): smooth, the same
for ζ and −ζ, and without the discontinuity at 180° that a sign-canonicalised quaternion input has
(we measured rollouts trapped at 180° with a w ≥ 0 quaternion input).

Architecture (after Pérez-Dattari et al., PUMA, MIT licence; re-written here):
encoder ρ = 3 linear layers with LayerNorm + GELU between them, output the latent y;
decoder φ = LayerNorm, 2 hidden GELU layers, a linear output, scaled by the data's maximum
|acceleration| (or |velocity|). Inputs are normalised by constants stored as buffers (so they are
saved and strictly checked with the weights).

Injective encoder: with ``skip`` = c > 0 the latent is ``y = [ρ_net(f), c f]`` (f the normalised
input), so ``‖y − y_g‖ ≥ c ‖f − f_g‖``: condition (2) of the stability theorem
(``ρ(x) = y_g ⇒ x = x_g``) holds by construction and the latent distance is radially unbounded
(the LayerNorm layers alone saturate far from the data, so a diverging rollout could otherwise
keep a shrinking latent distance; we measured exactly that failure).

Goal equilibrium: with ``pin_goal`` the output is ``s ⊙ (φ(ρ(x, ẋ)) − φ(ρ(x_g, 0)))`` so that
``f(x_g, 0) = 0`` exactly, whatever the weights (the goal is an equilibrium by construction;
its stability is what the triplet loss trains).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import partial

import torch
from torch import nn
from torch.nn import functional as F

from . import manifold
from .settings import NetConfig


@dataclass(frozen=True)
class StateSpec:
    """The space of a primitive: ``n_pos`` position dims, optional S³ part, order 1 or 2."""

    n_pos: int
    orientation: bool
    order: int

    def __post_init__(self):
        if self.n_pos < 1 or self.order not in (1, 2):
            raise ValueError(f"invalid state spec {self}")

    @property
    def tangent_dim(self) -> int:
        """Dimension of a velocity or acceleration: n_pos (+ 3 for ω)."""
        return self.n_pos + (3 if self.orientation else 0)

    @property
    def input_dim(self) -> int:
        return self.n_pos + (9 if self.orientation else 0) + (
            self.tangent_dim if self.order == 2 else 0)




class PumaNet(nn.Module):
    """Encoder ρ and decoder φ with input/output normalisation (see module docstring)."""

    def __init__(self, spec: StateSpec, cfg: NetConfig, pos_scale, vel_scale, out_scale):
        super().__init__()
        self.spec, self.cfg = spec, cfg
        w, z = cfg.width, cfg.latent_dim
        self.encoder = nn.Sequential(
            nn.Linear(spec.input_dim, w), nn.LayerNorm(w), nn.GELU(),
            nn.Linear(w, w), nn.LayerNorm(w), nn.GELU(),
            nn.Linear(w, z),
        )
        zd = z + (spec.input_dim if cfg.skip > 0 else 0)
        self.decoder = nn.Sequential(
            nn.LayerNorm(zd),
            nn.Linear(zd, w), nn.GELU(),
            nn.Linear(w, w), nn.GELU(),
            nn.Linear(w, spec.tangent_dim),
        )
        self.register_buffer("pos_scale", torch.as_tensor(pos_scale, dtype=torch.float32))
        self.register_buffer("vel_scale", torch.as_tensor(vel_scale, dtype=torch.float32))
        self.register_buffer("out_scale", torch.as_tensor(out_scale, dtype=torch.float32))
        self._goal_out: torch.Tensor | None = None
        self._shared_goal: tuple[torch.Tensor, torch.Tensor] | None = None
        self._layers: tuple | None = None  # the layers as functions (training: share_goal)

    # --- pieces -------------------------------------------------------------------------

    def features(self, pos, quat, vel) -> torch.Tensor:
        """Normalised network input ``[e/s_p, vec R(ζ), ẋ/s_v]``."""
        parts = [pos / self.pos_scale]
        if self.spec.orientation:
            parts.append(manifold.quat_to_matrix_flat(quat))
        if self.spec.order == 2:
            parts.append(vel / self.vel_scale)
        return torch.cat(parts, dim=-1)

    def encode(self, pos, quat=None, vel=None) -> torch.Tensor:
        """Latent ``y = ρ(x, ẋ)`` (vel None means ẋ = 0 for a second-order net); with ``skip``
        c > 0, ``[ρ_net(f), c f]`` (c = 1 multiplies nothing: ``1 · f`` is f to the bit)."""
        if self.spec.order == 2 and vel is None:
            vel = pos.new_zeros(pos.shape[:-1] + (self.spec.tangent_dim,))
        f = self.features(pos, quat, vel)
        if self._layers is None:
            y = self.encoder(f)
        else:
            y = _apply(self._layers[0], f)
        if self.cfg.skip <= 0:
            return y
        return torch.cat((y, f if self.cfg.skip == 1.0 else self.cfg.skip * f), dim=-1)

    def _decode(self, y: torch.Tensor) -> torch.Tensor:
        """``φ(y)``: the decoder's layers (as functions between :meth:`share_goal` and
        :meth:`release_goal`)."""
        return self.decoder(y) if self._layers is None else _apply(self._layers[1], y)

    def goal_state(self, batch_shape=(), like: torch.Tensor | None = None):
        """The goal ``(0, identity, 0)`` as tensors."""
        kw = {"dtype": like.dtype if like is not None else torch.float32}
        pos = torch.zeros(*batch_shape, self.spec.n_pos, **kw)
        quat = None
        if self.spec.orientation:
            quat = torch.zeros(*batch_shape, 4, **kw)
            quat[..., 3] = 1.0
        vel = None
        if self.spec.order == 2:
            vel = torch.zeros(*batch_shape, self.spec.tangent_dim, **kw)
        return pos, quat, vel

    def goal_latent(self) -> torch.Tensor:
        """``y_g = ρ(x_g, 0)`` (1, latent)."""
        if self._shared_goal is not None:
            return self._shared_goal[0]
        return self.encode(*self.goal_state((1,)))

    def share_goal(self) -> None:
        """Training: compute ``y_g`` and ``φ(y_g)`` once (with their graph) for every call until
        :meth:`release_goal`, instead of once per call (a rollout calls the network per step;
        the values and gradients are the same, the operations ~half).

        Until then the layers also run as functions (:func:`_functions`): each linear layer's
        ``Wᵀ`` is taken once for all calls, not once per call (the same products, and the
        weights' gradients summed in the same order)."""
        self._shared_goal = None
        self._layers = (_functions(self.encoder), _functions(self.decoder))
        yg = self.goal_latent()
        self._shared_goal = (yg, self._decode(yg))

    def release_goal(self) -> None:
        self._shared_goal = None
        self._layers = None

    def cache_goal(self) -> None:
        """Freeze ``φ(ρ(x_g, 0))`` for inference (the weights do not change any more)."""
        with torch.no_grad():
            self._goal_out = self.decoder(self.goal_latent())

    # --- forward ------------------------------------------------------------------------

    def forward(self, pos, quat=None, vel=None) -> torch.Tensor:
        """Acceleration (order 2) or velocity (order 1) in physical units, shape (..., tangent)."""
        return self.head(self.encode(pos, quat, vel))

    def head(self, y: torch.Tensor) -> torch.Tensor:
        """The output for a latent ``y = ρ(x, ẋ)``: ``s ⊙ (φ(y) − φ(y_g))`` (training reuses the
        latents of its rollouts in the stability loss instead of encoding the states again)."""
        return self.output(y, self.goal_offset())

    def output(self, y: torch.Tensor, goal_out: torch.Tensor | None) -> torch.Tensor:
        """``s ⊙ (φ(y) − goal_out)`` with a given goal offset (:meth:`goal_offset`; None: none
        subtracted): :meth:`head`'s arithmetic, for a caller that holds the offset."""
        out = self._decode(y)
        if goal_out is not None:
            out = out - goal_out
        return out * self.out_scale

    def goal_offset(self) -> torch.Tensor | None:
        """``φ(ρ(x_g, 0))`` (1, tangent), which ``pin_goal`` subtracts from the output (None
        without it): the shared one in training (:meth:`share_goal`), else computed (training
        mode) or the cached one (:meth:`cache_goal`)."""
        if not self.cfg.pin_goal:
            return None
        if self._shared_goal is not None:
            return self._shared_goal[1]
        if self.training or self._goal_out is None:
            return self._decode(self.goal_latent())
        return self._goal_out

    def train(self, mode: bool = True):
        self._goal_out = None
        self._shared_goal = None
        self._layers = None
        return super().train(mode)


def _functions(seq: nn.Sequential) -> tuple:
    """The layers of ``seq`` as functions of a 2-D input (rows, features), each the op its
    module's forward runs: ``addmm(b, x, Wᵀ)`` with ``Wᵀ`` taken here once (``F.linear`` takes
    it at every call), ``layer_norm``, ``gelu``. The module calls' own overhead (hooks, lookups)
    is gone too; the values are the modules' to the bit."""
    out = []
    for m in seq:
        if isinstance(m, nn.Linear):
            out.append(partial(torch.addmm, m.bias, mat2=m.weight.t()))
        elif isinstance(m, nn.LayerNorm):
            out.append(partial(F.layer_norm, normalized_shape=m.normalized_shape,
                               weight=m.weight, bias=m.bias, eps=m.eps))
        elif isinstance(m, nn.GELU):
            out.append(partial(F.gelu, approximate=m.approximate))
        else:
            raise TypeError(f"no function for layer {m}")
    return tuple(out)


def _apply(layers: tuple, x: torch.Tensor) -> torch.Tensor:
    """``layers`` (:func:`_functions`) on x (..., features): as rows (B, features), as
    ``F.linear`` runs an input of more dimensions (its rows flattened, the result viewed back)."""
    shape = x.shape
    if x.dim() != 2:
        x = x.reshape(-1, shape[-1])
    for layer in layers:
        x = layer(x)
    return x if len(shape) == 2 else x.view(*shape[:-1], x.shape[-1])


def potential(net: PumaNet, pos: torch.Tensor, quat: torch.Tensor | None):
    """``ψ = ‖ρ(x_g, 0) − ρ(x, 0)‖²`` and its gradient, batched (B, ·).

    Returns ``(ψ (B,), ∂ψ/∂e (B, n), ∂ψ/∂δθ (B, 3) | None)``; the orientation gradient is taken
    w.r.t. a small world-frame rotation δθ applied as ``ζ ← exp(δθ) ⊗ ζ`` [1/rad].
    """
    with torch.enable_grad():
        pos = pos.detach().clone().requires_grad_(True)
        inputs = [pos]
        if quat is not None:
            dtheta = torch.zeros(quat.shape[:-1] + (3,), dtype=quat.dtype, requires_grad=True)
            quat = manifold.quat_mul(manifold.quat_exp(dtheta), quat.detach())
            inputs.append(dtheta)
        yg = net.goal_latent().detach()
        psi = ((net.encode(pos, quat) - yg) ** 2).sum(-1)
        grads = torch.autograd.grad(psi.sum(), inputs)
    return psi.detach(), grads[0], (grads[1] if len(grads) > 1 else None)
