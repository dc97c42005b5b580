"""PUMA losses: multi-step imitation, triplet stability, ψ-compatibility and boundary.

``ℓ = ℓ_IL + λ ℓ_stable + λ_ψ ℓ_compat + λ_p ℓ_path + λ_b ℓ_boundary``.

- ``ℓ_IL``: from a demonstration state x_k, roll the network out W steps of Δt (closed loop) and
  take the mean squared error against x_{k+1..k+W}: positions divided by the position scale, all
  four quaternion components (sign aligned), and velocities (weight ``w_v``) divided by their scale.
- ``ℓ_stable`` (Pérez-Dattari et al.): over rollouts y_t = ρ(x_t, ẋ_t) from random workspace states,
  ``mean max(0, m + d(y_g, y_{t+1}) − (1 − rΔt) d(y_g, y_t))`` (squared if ``squared``), d
  Euclidean; r = 0 is the original triplet loss, r > 0 asks for an exponential decrease.
- ``ℓ_compat``: the potential ψ(x) = ‖ρ(x_g, 0) − ρ(x, 0)‖² must decrease along f(x, 0) at rest,
  i.e. ``−∂ψᵀ f(x, 0) > 0``; enforced as a hinge on a finite step of length ε along f(x, 0)/‖f‖,
  at the stability starts or at uniform samples of the workspace beyond a ball around the goal
  (``training.compat_states``: the states the evaluation judges), ε a length or a share of the
  workspace (``training.compat_step``).
- ``ℓ_path``: ψ must also fall along paths, not only at rest: over consecutive states x_k, x_{k+1}
  of the demonstration windows and of the stability rollouts that started at rest (the model's
  own paths from anywhere in the workspace), ``mean max(0, m + d(y_g, ρ(x_{k+1}, 0)) −
  d(y_g, ρ(x_k, 0)))``, the states held fixed (only the potential is shaped). Compatibility at
  rest says nothing about a moving state; this term makes the potential that CPM dissipates fall
  along PUMA's paths, so ψ does not rise while CPM follows them.
- ``ℓ_boundary``: squared distance of rollout positions outside the workspace box (normalised).
"""

from __future__ import annotations

import torch

from . import dynamics, manifold
from .network import PumaNet


def imitation_loss(net: PumaNet, target, dt: float, vel_weight: float = 0.1,
                   pos_weight: float = 1.0) -> torch.Tensor:
    """Closed-loop window loss. ``target = (pos (B, W+1, n), quat (B, W+1, 4) | None, vel)``."""
    pos_t, quat_t, vel_t = target
    window = pos_t.shape[1] - 1
    state = (pos_t[:, 0], quat_t[:, 0] if quat_t is not None else None,
             vel_t[:, 0] if net.spec.order == 2 else None)
    rolled = dynamics.stack(dynamics.rollout(net, state, dt, window)[1:])
    return imitation_error(net, rolled, target, vel_weight, pos_weight)


def imitation_error(net: PumaNet, rolled, target, vel_weight: float = 0.1,
                    pos_weight: float = 1.0) -> torch.Tensor:
    """The window loss of rollouts ``rolled = (pos, quat, vel)`` (B, W, ·), the states after
    steps 1..W from the first sample of each ``target`` window: squared position errors over
    the position scale (× ``pos_weight``), all four quaternion components (sign aligned) and the
    velocities (× ``vel_weight``) over their scale."""
    pos_t, quat_t, vel_t = target
    pos, quat, vel = rolled
    loss = (((pos - pos_t[:, 1:]) / net.pos_scale) ** 2).mean()
    if pos_weight != 1.0:
        loss = pos_weight * loss
    if quat is not None:
        qt = quat_t[:, 1:]
        sign = torch.sign((quat * qt).sum(-1, keepdim=True) + 1e-12)
        loss = loss + ((quat - sign * qt) ** 2).sum(-1).mean()
    if vel is not None and vel_weight > 0:
        loss = loss + vel_weight * (((vel - vel_t[:, 1:]) / net.vel_scale) ** 2).mean()
    return loss


def _hinge(x: torch.Tensor, squared: bool) -> torch.Tensor:
    h = torch.relu(x)
    return (h * h).mean() if squared else h.mean()


def stability_terms(net, states, dt, margin, squared=False, low=None, high=None, rate=0.0,
                    latents=None):
    """The triplet hinge and boundary terms over rollout states (a list, or stacked (B, T+1, ·)).

    ``max(0, m + d_{t+1} − (1 − r Δt) d_t)``: with ``rate`` r [1/s] > 0 the latent distance must
    also shrink by a fraction r Δt per step (exponential decrease), which keeps the hinge active
    near the goal where the absolute margin m alone is either trivial or unattainable.
    ``latents`` (B, T+1, ·): the states' latents if the rollout has them (else encoded here).
    """
    pos, quat, vel = states if isinstance(states, tuple) else dynamics.stack(states)
    y = net.encode(pos, quat, vel) if latents is None else latents
    dist = (y - net.goal_latent()).norm(dim=-1)  # (B, T+1)
    stable = _hinge(margin + dist[:, 1:] - (1.0 - rate * dt) * dist[:, :-1], squared)
    boundary = pos.new_zeros(())
    if low is not None:
        out = torch.relu(pos - high) + torch.relu(low - pos)
        boundary = ((out / net.pos_scale) ** 2).sum(-1).mean()
    return stable, boundary


def compat_loss(net: PumaNet, pos, quat, eps: float, margin: float) -> torch.Tensor:
    """Hinge ``max(0, m + d(y_g, ρ(x + ε f̂, 0)) − d(y_g, ρ(x, 0)))`` at rest, f̂ = f/‖f‖."""
    vel = None
    if net.spec.order == 2:
        vel = pos.new_zeros(pos.shape[:-1] + (net.spec.tangent_dim,))
    y0 = net.encode(pos, quat, vel)
    f = net.head(y0)
    step = eps * f / f.norm(dim=-1, keepdim=True).clamp_min(1e-9)
    n = net.spec.n_pos
    pos2 = pos + step[..., :n]
    quat2 = manifold.step_orientation(quat, step[..., n:], 1.0) if quat is not None else None
    yg = net.goal_latent()
    d0 = (y0 - yg).norm(dim=-1)
    d1 = (net.encode(pos2, quat2) - yg).norm(dim=-1)
    return torch.relu(margin + d1 - d0).mean()


def path_potential_loss(net: PumaNet, pos, quat, margin: float, rows=None) -> torch.Tensor:
    """Hinge ``max(0, m + d(y_g, ρ(x_{k+1}, 0)) − d(y_g, ρ(x_k, 0)))`` along paths
    ``pos (B, T, n)``, ``quat (B, T, 4) | None`` (detached: only ρ is shaped); samples resting on
    the goal give m. ``rows`` (B,) bool: only those paths count (none: zero)."""
    pos = pos.detach()
    quat = quat.detach() if quat is not None else None
    if rows is not None:
        if not bool(rows.any()):
            return pos.new_zeros(())
        pos, quat = pos[rows], (quat[rows] if quat is not None else None)
    d = (net.encode(pos, quat) - net.goal_latent()).norm(dim=-1)  # (B, T)
    return torch.relu(margin + d[:, 1:] - d[:, :-1]).mean()
